"""Topology helpers on ``(vertices, faces)`` arrays: components, boundaries, orientation, quality."""

from __future__ import annotations

import numpy as np

from core.mesh import boundary_loops, edge_counts
from core.proxy.config import ENCLOSE_BINS, ENCLOSE_COVERAGE, SLIVER_ANGLE_DEG

#: Faces sampled per patch, and rays per face side, for the visibility orientation test.
VISIBILITY_FACES = 32
VISIBILITY_RAYS = 16


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Triangle areas, ``(F,)`` float64, for ``vertices`` (V, 3) and ``faces`` (F, 3) int."""
    v = np.asarray(vertices, np.float64)
    e1 = v[faces[:, 1]] - v[faces[:, 0]]
    e2 = v[faces[:, 2]] - v[faces[:, 0]]
    return 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)


def face_components(num_vertices: int, faces: np.ndarray) -> np.ndarray:
    """Connected component label of each face (sharing a vertex connects), ``(F,)`` int64."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    e = faces[:, [0, 1, 1, 2]].reshape(-1, 2)
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(num_vertices,) * 2)
    _, labels = connected_components(adj, directed=False)
    return labels[faces[:, 0]].astype(np.int64)


def compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drop unreferenced vertices. Returns ``(vertices, faces, kept)`` with ``kept`` (V',) int64
    the old index of each new vertex."""
    used = np.zeros(len(vertices), bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    kept = np.flatnonzero(used)
    return vertices[kept], remap[faces].astype(np.int64), kept


def drop_small_components(
    vertices: np.ndarray, faces: np.ndarray, min_fraction: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """Remove connected parts whose area is below ``min_fraction`` of the largest part's area.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int64
    min_fraction : float in [0, 1)

    Returns
    -------
    vertices : (V', 3), faces : (F', 3) int64, dropped : number of parts removed
    """
    labels = face_components(len(vertices), faces)
    area = np.bincount(labels, weights=face_areas(vertices, faces))
    present = np.unique(labels)
    keep = area >= min_fraction * area[present].max()
    keep_face = keep[labels]
    dropped = int(len(present) - keep[present].sum())
    v, f, _ = compact(vertices, faces[keep_face])
    return v, f, dropped


def orient_consistently(vertices: np.ndarray, faces: np.ndarray, seed: int = 0) -> np.ndarray:
    """Faces re-wound so neighbours agree and each patch faces outward, ``(F, 3)`` int64.

    Patches are oriented by breadth-first search (libigl ``bfs_orient``). A patch that goes
    around the vertical axis through the garment's area centroid (a skirt layer, a bodice) is
    flipped when most of its area faces that axis. Any other patch (a strap, a separate sleeve)
    is flipped when its back side sees the outside more than its front side: rays from sampled
    faces into each hemisphere, counted when they escape (the ambient-occlusion test of
    Takayama et al. 2014, libigl's Embree ray caster).
    """
    import igl

    f = np.ascontiguousarray(faces, np.int64)
    ff, patch = igl.bfs_orient(f)
    ff = np.asarray(ff, np.int64)
    patch = np.asarray(patch, np.int64).reshape(-1)
    v = np.asarray(vertices, np.float64)
    tri = v[ff]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 * area
    centre = tri.mean(axis=1)
    area = np.linalg.norm(normal, axis=1)
    axis = (centre * area[:, None]).sum(0) / max(area.sum(), 1e-30)
    radial = centre - axis
    radial[:, 1] = 0.0
    score = np.bincount(patch, weights=(normal * radial).sum(1))
    ang = np.arctan2(radial[:, 2], radial[:, 0])
    sector = ((ang + np.pi) / (2 * np.pi) * ENCLOSE_BINS).astype(np.int64) % ENCLOSE_BINS
    covered = np.zeros((len(score), ENCLOSE_BINS), bool)
    covered[patch, sector] = True
    beside = np.flatnonzero(covered.mean(1) < ENCLOSE_COVERAGE)
    if len(beside):
        vis = _visibility(v, ff, patch, beside, area, np.random.default_rng(seed))
        decided = vis != 0
        score[beside[decided]] = vis[decided]
    flip = score[patch] < 0
    ff[flip] = ff[flip][:, ::-1]
    return ff


def _visibility(
    v: np.ndarray,
    f: np.ndarray,
    patch: np.ndarray,
    which: np.ndarray,
    area: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """Escaping rays from the front minus from the back, per patch in ``which`` (float64)."""
    import igl.embree

    scene = igl.embree.EmbreeIntersector()
    scene.init(np.asfortranarray(v, np.float32), np.asfortranarray(f, np.int32), True)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    eps = 1e-5 * diag
    out = np.zeros(len(which))
    for k, p in enumerate(which):
        faces_p = np.flatnonzero(patch == p)
        w = area[faces_p]
        pick = (
            rng.choice(faces_p, size=VISIBILITY_FACES, p=w / w.sum())
            if w.sum() > 0
            else faces_p[:1]
        )
        for fi in pick:
            c = tri[fi].mean(0)
            d = rng.normal(size=(VISIBILITY_RAYS, 3))
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            d *= np.sign(d @ n[fi])[:, None] + (d @ n[fi] == 0)[:, None]
            for side in (1.0, -1.0):
                for dk in d:
                    dd = (side * dk).astype(np.float32)
                    o = (c + side * eps * n[fi]).astype(np.float32)
                    hit, _, _, _ = scene.intersectRay_first(o, dd, 0.0, np.inf)
                    out[k] += side * (hit < 0)
    return out


def mesh_stats(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """Counts and topology for the report: components, manifoldness, boundary loops, quality."""
    edges, counts = edge_counts(faces)
    loops = boundary_loops(faces)
    v = np.asarray(vertices, np.float64)
    tri = v[faces]
    angles = []
    for i in range(3):
        a = tri[:, (i + 1) % 3] - tri[:, i]
        b = tri[:, (i + 2) % 3] - tri[:, i]
        cos = (a * b).sum(1) / np.maximum(
            np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-30
        )
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    min_angle = np.min(angles, axis=0)
    n_components = len(np.unique(face_components(len(v), faces))) if len(faces) else 0
    non_manifold = int((counts > 2).sum())
    # Directed edge used twice in the same direction: neighbours disagree on orientation.
    d = np.asarray(faces, np.int64)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    _, dcounts = np.unique(d[:, 0] * (len(v) + 1) + d[:, 1], return_counts=True)
    return {
        "vertices": int(len(v)),
        "faces": int(len(faces)),
        "edges": int(len(edges)),
        "components": int(n_components),
        "non_manifold_edges": non_manifold,
        "inconsistent_edges": int((dcounts > 1).sum()),
        "edge_manifold": non_manifold == 0,
        "boundary_edges": int((counts == 1).sum()),
        "boundary_loops": len(loops),
        "boundary_loop_lengths": [int(len(lp)) for lp in loops[:16]],
        "euler_characteristic": int(len(v) - len(edges) + len(faces)),
        "min_angle_deg": float(min_angle.min()) if len(faces) else 0.0,
        "slivers": int((min_angle < SLIVER_ANGLE_DEG).sum()),
        "area_m2": float(face_areas(v, faces).sum()),
    }
