"""Fold smoothing (libigl) and decimation to a vertex count (libigl, fast-simplification)."""

from __future__ import annotations

import math

import numpy as np

from core.proxy.config import VERTEX_COUNT_TOLERANCE
from core.proxy.metrics import point_to_mesh
from core.proxy.topology import compact, edge_counts, face_areas

#: Implicit steps the smoothing flow is split into (one factorisation, reused).
SMOOTH_STEPS = 3
#: Largest cotangent weight the smoothing uses (cot 1 degree).
MAX_COT = 1.0 / math.tan(math.radians(1.0))
#: Decimation retries to land on the requested vertex count.
DECIMATE_ATTEMPTS = 5
#: Tangential relaxation passes after decimation (see :func:`relax`).
RELAX_ITERATIONS = 3


def smooth_details(vertices: np.ndarray, faces: np.ndarray, scale: float) -> np.ndarray:
    """Smooth away folds narrower than ``scale`` metres, keeping boundary vertices fixed.

    Implicit mean-curvature-like flow with libigl's cotangent Laplacian ``L`` and Voronoi mass
    ``M``: ``(M - dt L) x' = M x`` over ``SMOOTH_STEPS`` steps of total time
    ``T = scale**2 / (2 pi**2)``, which damps a fold of wavelength ``scale`` to about 20 % of its
    height and one of ``3 * scale`` by less than 25 %. Boundary loops (hem, waist, cuffs) stay put
    and vertices move only along their normal (no sliding within the surface).

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int64
    scale : float, metres (0 returns the input)

    Returns
    -------
    (V, 3) float64
    """
    import igl
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.linalg import splu

    v = np.asarray(vertices, np.float64)
    if scale <= 0 or len(faces) == 0:
        return v.copy()
    f = np.ascontiguousarray(faces, np.int64)
    # Cotangent weights clipped to [0, cot(1 degree)]: obtuse and degenerate triangles can give
    # negative or huge weights; clipped ones keep the flow a contraction (no overshoot, no NaN).
    raw = igl.cotmatrix(v, f).tocoo()
    off = raw.row != raw.col
    w = np.nan_to_num(raw.data[off], nan=0.0, posinf=MAX_COT, neginf=0.0).clip(0.0, MAX_COT)
    lap = coo_matrix((w, (raw.row[off], raw.col[off])), shape=raw.shape).tocsr()
    lap = lap - diags(np.asarray(lap.sum(axis=1)).ravel())
    mass = igl.massmatrix(v, f, igl.MASSMATRIX_TYPE_VORONOI).diagonal()
    mass = np.where(np.isfinite(mass) & (mass > 0), mass, 0.0)
    floor = max(float(np.median(mass[mass > 0])) if (mass > 0).any() else 1.0, 1e-30) * 1e-3
    mass = np.maximum(mass, floor)
    used = np.zeros(len(v), bool)
    used[f.ravel()] = True
    edges, counts = edge_counts(f)
    fixed = np.zeros(len(v), bool)
    fixed[edges[counts != 2].ravel()] = True  # boundary and non-manifold edges stay
    fixed |= ~used
    free = np.flatnonzero(~fixed)
    if len(free) == 0:
        return v.copy()
    dt = scale**2 / (2 * math.pi**2) / SMOOTH_STEPS
    a = (diags(mass) - dt * lap).tocsr()
    a_ff = a[free][:, free].tocsc()
    a_fb = a[free][:, np.flatnonzero(fixed)]
    solve = splu(a_ff).solve
    x = v.copy()
    xb = v[fixed]
    for _ in range(SMOOTH_STEPS):
        rhs = mass[free, None] * x[free] - a_fb @ xb
        x[free] = solve(rhs)
    if not np.isfinite(x).all():  # a degenerate Laplacian: keep the unsmoothed surface
        return v.copy()
    # Keep only the motion along the vertex normal. With clipped weights on sheared or obtuse
    # triangles the flow also slides vertices within the surface (5 cm on a T-shirt's sides at
    # a 2 cm scale), which drags the surface away from its fixed boundary; folds only need the
    # normal motion.
    tri = v[f]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vn = np.zeros_like(v)
    for k in range(3):
        np.add.at(vn, f[:, k], fn)
    vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
    return v + ((x - v) * vn).sum(axis=1, keepdims=True) * vn


def subdivide_to(
    vertices: np.ndarray, faces: np.ndarray, min_vertices: int
) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint-subdivide (shape unchanged) until there are at least ``min_vertices`` vertices."""
    import trimesh

    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    while len(v) < min_vertices:
        v, f = trimesh.remesh.subdivide(v, f)
    return v, np.asarray(f, np.int64)


def decimate(
    vertices: np.ndarray,
    faces: np.ndarray,
    target: int,
    *,
    aggressiveness: float = 7.0,
    uniform: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Edge-collapse decimation to about ``target`` vertices, keeping every boundary loop.

    On an oriented 2-manifold (the garments this stage sees after cleaning) the collapses are
    libigl's: quadric error (``igl.qslim``) or, with ``uniform``, shortest edge first with
    midpoint placement (``igl.decimate``, a cheap way to even out a dense mesh before
    smoothing). Both check the link condition and treat a boundary as edges to a vertex at
    infinity, so no collapse joins two boundary stretches: a strap one triangle wide, a slit
    or an armhole keeps its loop. Anything else (non-manifold edges or vertices) goes to
    fast-simplification's quadric collapses, which never flip a triangle but may join two
    sides of a thin strip.

    The face budget comes from Euler's formula (``F = 2 (V - chi) - B``) and is corrected from
    the vertex count reached, up to ``DECIMATE_ATTEMPTS`` times, until within
    ``VERTEX_COUNT_TOLERANCE``. A mesh with fewer vertices than ``target`` is first
    midpoint-subdivided, which does not move the surface.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    target : int, vertices wanted
    aggressiveness : fast-simplification's (non-manifold input only)
    uniform : shortest edge first instead of quadric error (manifold input only)

    Returns
    -------
    vertices : (V', 3) float64, faces : (F', 3) int64
    """
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    if len(v) < target:
        v, f = subdivide_to(v, f, target)
    if len(v) <= target * (1 + VERTEX_COUNT_TOLERANCE):
        return v, f
    edges, counts = edge_counts(f)
    chi = len(v) - len(edges) + len(f)
    n_boundary = len(np.unique(edges[counts == 1]))
    b_target = n_boundary * math.sqrt(target / len(v))
    want = max(4, int(round(2 * (target - chi) - b_target)))
    collapse = _igl_collapse(uniform) if is_oriented_manifold(f) else _fast_collapse(aggressiveness)
    best = None
    for _ in range(DECIMATE_ATTEMPTS):
        want = min(want, len(f) - 1)
        dv, df = _clean(*collapse(v, f, int(want)))
        err = abs(len(dv) - target)
        if best is None or err < abs(len(best[0]) - target):
            best = (dv, df)
        if err <= VERTEX_COUNT_TOLERANCE * target:
            break
        want = max(4, want + 2 * (target - len(dv)))
    return best


def is_oriented_manifold(faces: np.ndarray) -> bool:
    """Whether ``faces`` (F, 3) int form an oriented 2-manifold, possibly with boundary: every
    edge in one or two faces (used once each way) and the faces around every vertex one fan
    (no two cones or sheets meeting at a single vertex)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(faces, np.int64)
    if len(f) == 0:
        return False
    edges, counts = edge_counts(f)
    if counts.max() > 2:
        return False
    n = int(f.max()) + 1
    directed = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    key = directed[:, 0] * n + directed[:, 1]
    if len(np.unique(key)) != len(key):
        return False
    # Fans: face corners (face, vertex) joined across the edges two faces share; a manifold
    # vertex has its corners in one group.
    face_of = np.repeat(np.arange(len(f)), 3)
    reverse = directed[:, 1] * n + directed[:, 0]
    order = np.argsort(key)
    pos = np.searchsorted(key[order], reverse)
    pos = np.minimum(pos, len(key) - 1)
    twin = order[pos]
    shared = key[twin] == reverse
    a, b = face_of[shared], face_of[twin[shared]]

    def cid(fi: np.ndarray, vi: np.ndarray) -> np.ndarray:
        """Corner index (face * 3 + slot) of vertex ``vi`` in face ``fi``."""
        return fi * 3 + np.argmax(f[fi] == vi[:, None], axis=1)

    src = directed[shared]
    ca = np.concatenate([cid(a, src[:, 0]), cid(a, src[:, 1])])
    cb = np.concatenate([cid(b, src[:, 0]), cid(b, src[:, 1])])
    graph = coo_matrix((np.ones(len(ca)), (ca, cb)), shape=(3 * len(f),) * 2)
    _, label = connected_components(graph, directed=False)
    fans = np.unique(np.stack([f.ravel(), label], axis=1), axis=0)[:, 0]
    return bool(np.bincount(fans).max() <= 1)


def _igl_collapse(uniform: bool):
    def run(v: np.ndarray, f: np.ndarray, faces_wanted: int):
        import igl

        fn = igl.decimate if uniform else igl.qslim
        out = fn(np.asfortranarray(v, np.float64), np.asfortranarray(f, np.int32), faces_wanted)
        return np.asarray(out[-4], np.float64), np.asarray(out[-3], np.int64)

    return run


def _fast_collapse(aggressiveness: float):
    def run(v: np.ndarray, f: np.ndarray, faces_wanted: int):
        import fast_simplification

        dv, df = fast_simplification.simplify(
            np.ascontiguousarray(v, np.float32),
            np.ascontiguousarray(f, np.int32),
            target_count=faces_wanted,
            agg=aggressiveness,
        )
        return np.asarray(dv, np.float64), np.asarray(df, np.int64)

    return run


def _clean(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop repeated-index and zero-area faces, then unreferenced vertices."""
    rep = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    f = f[~rep]
    f = f[face_areas(v, f) > 0]
    v, f, _ = compact(v, f)
    return v, f


def relax(
    vertices: np.ndarray,
    faces: np.ndarray,
    reference_vertices: np.ndarray,
    reference_faces: np.ndarray,
    iterations: int = RELAX_ITERATIONS,
) -> np.ndarray:
    """Even out triangle shapes after decimation without leaving the surface.

    Each iteration moves every interior vertex half-way towards the centroid of its neighbours,
    within its tangent plane, then back onto the reference surface (closest point). Boundary
    vertices stay. An iteration that would flip a triangle (turn its normal by more than 90
    degrees) is undone for that triangle's vertices.

    Parameters
    ----------
    vertices : (V, 3) float, faces : (F, 3) int64
        The decimated mesh.
    reference_vertices : (Vr, 3) float, reference_faces : (Fr, 3) int64
        The surface to stay on (the mesh before decimation).

    Returns
    -------
    (V, 3) float64
    """
    from scipy.sparse import coo_matrix

    v = np.asarray(vertices, np.float64).copy()
    f = np.asarray(faces, np.int64)
    if len(f) == 0 or iterations <= 0:
        return v
    e = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    adj = coo_matrix(
        (np.ones(len(e) * 2), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
        shape=(len(v),) * 2,
    ).tocsr()
    adj.data[:] = 1.0
    deg = np.asarray(adj.sum(axis=1)).ravel()
    edges, counts = edge_counts(f)
    fixed = np.zeros(len(v), bool)
    fixed[edges[counts != 2].ravel()] = True
    fixed |= deg == 0
    free = np.flatnonzero(~fixed)

    def normals(x):
        t = x[f]
        return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])

    for _ in range(iterations):
        fn = normals(v)
        vn = np.zeros_like(v)
        for k in range(3):
            np.add.at(vn, f[:, k], fn)
        vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        delta = adj @ v / np.maximum(deg, 1)[:, None] - v
        delta -= (delta * vn).sum(1, keepdims=True) * vn
        new = v.copy()
        new[free] += 0.5 * delta[free]
        _, _, closest = point_to_mesh(new[free], reference_vertices, reference_faces)
        new[free] = closest
        bad = (normals(new) * fn).sum(1) <= 0
        if bad.any():
            new[f[bad].ravel()] = v[f[bad].ravel()]
        v = new
    return v
