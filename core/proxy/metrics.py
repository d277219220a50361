"""Distances between target and proxy: sampled Hausdorff distance and closest-point correspondence."""

from __future__ import annotations

import numpy as np

from core.proxy.config import Correspondence
from core.proxy.topology import face_areas


def sample_surface(
    vertices: np.ndarray, faces: np.ndarray, count: int, rng: np.random.Generator
) -> np.ndarray:
    """``count`` area-uniform random points on the surface, ``(count, 3)`` float64."""
    v = np.asarray(vertices, np.float64)
    a = face_areas(v, faces)
    if count <= 0 or a.sum() <= 0:
        return np.zeros((0, 3))
    fi = rng.choice(len(faces), size=count, p=a / a.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    w = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    return np.einsum("ni,nij->nj", w, v[faces[fi]])


def point_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray):
    """Closest points on a mesh (libigl AABB tree).

    Returns ``distance`` (N,) float64, ``face`` (N,) int64, ``closest`` (N, 3) float64.
    """
    import igl

    d2, face, closest = igl.point_mesh_squared_distance(
        np.ascontiguousarray(points, np.float64),
        np.ascontiguousarray(vertices, np.float64),
        np.ascontiguousarray(faces, np.int64),
    )
    return np.sqrt(np.maximum(d2, 0)), np.asarray(face, np.int64), np.asarray(closest)


def hausdorff(
    va: np.ndarray,
    fa: np.ndarray,
    vb: np.ndarray,
    fb: np.ndarray,
    *,
    samples: int = 20000,
    seed: int = 0,
) -> dict:
    """Two-sided Hausdorff distance between surfaces A and B, in the input's units.

    Each side is measured from all vertices plus ``samples`` area-uniform surface points to the
    exact closest point on the other surface, so it is a lower bound that converges with
    ``samples``. Returns ``a_to_b``, ``b_to_a`` (max), ``a_to_b_mean``, ``b_to_a_mean``, ``hausdorff``.
    """
    rng = np.random.default_rng(seed)
    pa = np.concatenate([np.asarray(va, np.float64), sample_surface(va, fa, samples, rng)])
    pb = np.concatenate([np.asarray(vb, np.float64), sample_surface(vb, fb, samples, rng)])
    dab, _, _ = point_to_mesh(pa, vb, fb)
    dba, _, _ = point_to_mesh(pb, va, fa)
    return {
        "a_to_b": float(dab.max()),
        "b_to_a": float(dba.max()),
        "a_to_b_mean": float(dab.mean()),
        "b_to_a_mean": float(dba.mean()),
        "hausdorff": float(max(dab.max(), dba.max())),
    }


def barycentric(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(N, 3)`` of ``points`` (N, 3) in ``triangles`` (N, 3, 3),
    clipped to the triangle and summing to 1 (degenerate triangles give their nearest corner)."""
    p = np.asarray(points, np.float64)
    t = np.asarray(triangles, np.float64)
    e0, e1, d = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0], p - t[:, 0]
    d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
    d20, d21 = (d * e0).sum(1), (d * e1).sum(1)
    den = d00 * d11 - d01 * d01
    good = den > 1e-30 * np.maximum(d00 * d11, 1e-300)
    safe = np.where(good, den, 1.0)
    b1 = np.where(good, (d11 * d20 - d01 * d21) / safe, 0.0)
    b2 = np.where(good, (d00 * d21 - d01 * d20) / safe, 0.0)
    w = np.clip(np.stack([1 - b1 - b2, b1, b2], axis=1), 0.0, None)
    s = w.sum(1, keepdims=True)
    w = np.where(s > 0, w / np.where(s > 0, s, 1), [1.0, 0.0, 0.0])
    bad = ~good
    if bad.any():
        dist = np.linalg.norm(t[bad] - p[bad, None], axis=2)
        w[bad] = np.eye(3)[np.argmin(dist, axis=1)]
    return w


def correspond(
    target_vertices: np.ndarray, proxy_vertices: np.ndarray, proxy_faces: np.ndarray
) -> Correspondence:
    """Closest point on the proxy for every target vertex.

    Parameters
    ----------
    target_vertices : (Vt, 3) float, proxy_vertices : (Vp, 3) float, proxy_faces : (Fp, 3) int
    """
    dist, face, closest = point_to_mesh(target_vertices, proxy_vertices, proxy_faces)
    tri = np.asarray(proxy_vertices, np.float64)[proxy_faces[face]]
    return Correspondence(
        face=face,
        barycentric=barycentric(closest, tri).astype(np.float32),
        distance=dist.astype(np.float32),
    )


def transfer_to_proxy(
    values: np.ndarray, correspondence: Correspondence, proxy_faces: np.ndarray, num_vertices: int
) -> tuple[np.ndarray, np.ndarray]:
    """Carry per-target-vertex values (colours, labels as one-hot) onto proxy vertices.

    Each target vertex adds its value to the three corners of its proxy face, weighted by its
    barycentric coordinates; each proxy vertex gets the weighted mean.

    Parameters
    ----------
    values : (Vt, C) float
    correspondence : from :func:`correspond`
    proxy_faces : (Fp, 3) int
    num_vertices : int, proxy vertex count Vp

    Returns
    -------
    values : (Vp, C) float32 (zero where no target vertex landed), weight : (Vp,) float32
    """
    vals = np.asarray(values, np.float64)
    if vals.ndim == 1:
        vals = vals[:, None]
    corners = proxy_faces[correspondence.face]  # (Vt, 3)
    w = correspondence.barycentric.astype(np.float64)
    acc = np.zeros((num_vertices, vals.shape[1]))
    wsum = np.zeros(num_vertices)
    for k in range(3):
        np.add.at(acc, corners[:, k], vals * w[:, k : k + 1])
        np.add.at(wsum, corners[:, k], w[:, k])
    out = np.where(wsum[:, None] > 0, acc / np.maximum(wsum, 1e-300)[:, None], 0.0)
    return out.astype(np.float32), wsum.astype(np.float32)
