"""Drive a detailed garment by its simulated proxy: a normal-offset embedding.

Each target vertex is tied to its closest point on the proxy at rest: the face, barycentric
coordinates, a distance along the proxy's interpolated normal there, and a small residual in the
face's tangent plane. Any pose of the proxy then places the target vertex: its closest point
moves with the proxy surface, the normal offset turns with the surface normal, and what the
interpolated normal does not reach is kept in the face's own frame (exact at rest and under rigid
motion). Inner layers,
ruffles and frills keep their rest offsets from the outer surface.

This is what the studio uses when simulating the full detailed target is too slow or unstable
(stacked layers a few millimetres apart, many loose parts): the target then follows the proxy's
dynamics exactly, without secondary motion of its own details.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InputError


@dataclass(frozen=True)
class Embedding:
    """Target vertices attached to a proxy mesh.

    Attributes
    ----------
    faces : (Fp, 3) int64, the proxy's faces
    face : (Vt,) int64, proxy face of each target vertex's closest point
    barycentric : (Vt, 3) float32, its barycentric coordinates (rows sum to 1)
    normal_offset : (Vt,) float32, signed distance along the interpolated proxy normal (metres)
    residual : (Vt, 3) float32, the rest of the offset in the face's frame (e1, e2, n), metres
    """

    faces: np.ndarray
    face: np.ndarray
    barycentric: np.ndarray
    normal_offset: np.ndarray
    residual: np.ndarray


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals: (V, 3) float64 for vertices (V, 3), faces (F, 3)."""
    v = np.asarray(vertices, np.float64)
    tri = v[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    out = np.zeros_like(v)
    for k in range(3):
        np.add.at(out, faces[:, k], n)
    return out / np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-12)


def _face_frames(tri: np.ndarray) -> np.ndarray:
    """Orthonormal frames (e1 along edge 0->1, e2 = n x e1, n) of triangles (N, 3, 3): (N, 3, 3),
    one frame per row-stacked axes."""
    e1 = tri[:, 1] - tri[:, 0]
    n = np.cross(e1, tri[:, 2] - tri[:, 0])
    e1 = e1 / np.maximum(np.linalg.norm(e1, axis=-1, keepdims=True), 1e-12)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return np.stack([e1, np.cross(n, e1), n], axis=1)


def embed(target: np.ndarray, proxy: np.ndarray, faces: np.ndarray, path=None) -> Embedding:
    """Attach ``target`` (Vt, 3) vertices to the proxy ``proxy`` (Vp, 3), ``faces`` (Fp, 3)."""
    from core.proxy.metrics import correspond

    target = np.asarray(target, np.float64)
    proxy = np.asarray(proxy, np.float64)
    faces = np.asarray(faces, np.int64)
    if target.ndim != 2 or target.shape[1] != 3 or not np.isfinite(target).all():
        raise InputError(f"target vertices must be finite (Vt, 3), got {target.shape}", path)
    if proxy.ndim != 2 or proxy.shape[1] != 3 or not np.isfinite(proxy).all() or not len(faces):
        raise InputError(f"proxy must be finite (Vp, 3) with faces, got {proxy.shape}", path)
    corr = correspond(target, proxy, faces)
    bary = corr.barycentric.astype(np.float64)
    tri = proxy[faces[corr.face]]
    point = np.einsum("ni,nij->nj", bary, tri)
    normal = _interpolated_normals(proxy, faces, corr.face, bary)
    delta = target - point
    d = np.einsum("nj,nj->n", delta, normal)
    rest = delta - d[:, None] * normal
    residual = np.einsum("nkj,nj->nk", _face_frames(tri), rest)
    return Embedding(
        faces=faces,
        face=corr.face.astype(np.int64),
        barycentric=corr.barycentric.astype(np.float32),
        normal_offset=d.astype(np.float32),
        residual=residual.astype(np.float32),
    )


def _interpolated_normals(vertices, faces, face, bary) -> np.ndarray:
    n = vertex_normals(vertices, faces)[faces[face]]
    n = np.einsum("ni,nij->nj", bary, n)
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)


def drive(embedding: Embedding, proxy_positions: np.ndarray) -> np.ndarray:
    """Target positions for every proxy frame: (T, Vt, 3) float32 from (T, Vp, 3)."""
    p = np.asarray(proxy_positions, np.float64)
    if p.ndim != 3 or p.shape[2] != 3 or p.shape[1] <= embedding.faces.max():
        raise InputError(f"proxy positions must be (T, Vp, 3) for this proxy, got {p.shape}")
    bary = embedding.barycentric.astype(np.float64)
    out = np.empty((len(p), len(embedding.face), 3), np.float32)
    for t, frame in enumerate(p):
        tri = frame[embedding.faces[embedding.face]]
        point = np.einsum("ni,nij->nj", bary, tri)
        normal = _interpolated_normals(frame, embedding.faces, embedding.face, bary)
        rest = np.einsum("nk,nkj->nj", embedding.residual, _face_frames(tri))
        out[t] = point + embedding.normal_offset[:, None] * normal + rest
    return out
