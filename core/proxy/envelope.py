"""Collapse stacked layers and ruffles into one outer surface: the radial envelope.

Assumption: the garment is worn around a vertical (Y) body axis and its outer surface is
star-shaped around that axis at every height (skirts, dresses, tubes, tiered and pleated skirts).
Horizontal rays cast inward from a cylinder around the garment stop at the outermost layer; the
hit points on a (height x angle) grid form one open surface whose top and bottom rows are then
snapped onto the garment's own waist and hem boundaries. Inner layers, linings and the inside of
ruffles are never hit, so they vanish.

When the assumption fails (sleeves, trouser legs, hoods) parts of the garment hide behind the
envelope far from it; :func:`envelope_error` measures that, and the pipeline's ``auto`` mode
then keeps the cleaned surface instead. When there is nothing to collapse (one layer, see
:func:`covered_fraction`) ``auto`` keeps it too: the envelope would only close armholes and
slits.
"""

from __future__ import annotations

import math

import numpy as np

from core.mesh import validate_mesh
from core.proxy.config import (
    CURTAIN_COS,
    ENCLOSE_BINS,
    ENCLOSE_COVERAGE,
    ENVELOPE_CHECK_SAMPLES,
    ENVELOPE_RAY_MARGIN,
    INWARD_COS,
)
from core.proxy.topology import compact, drop_small_components, edge_counts, face_areas


def garment_axis(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Centre of the vertical axis, ``(2,)`` float64 (x, z): the area-weighted surface centroid."""
    v = np.asarray(vertices, np.float64)
    a = face_areas(v, faces)
    c = v[faces].mean(axis=1)
    w = a / max(a.sum(), 1e-300)
    return np.array([(c[:, 0] * w).sum(), (c[:, 2] * w).sum()])


def cast_radial(
    vertices: np.ndarray,
    faces: np.ndarray,
    heights: np.ndarray,
    angles: np.ndarray,
    axis: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Outermost surface point along horizontal rays towards the axis.

    Parameters
    ----------
    vertices : (V, 3) float, faces : (F, 3) int
    heights : (N,) float, angles : (N,) float
        Y and azimuth (radians, measured from +X towards +Z) of each ray.
    axis : (2,) float
        (x, z) of the vertical axis.

    Returns
    -------
    points : (N, 3) float64
        Hit points (undefined where ``hit`` is False).
    hit : (N,) bool
        True where the ray met the surface before crossing the axis.
    """
    import igl.embree

    v = np.asarray(vertices, np.float64)
    radial = np.hypot(v[:, 0] - axis[0], v[:, 2] - axis[1])
    start = float(radial.max()) * (1.0 + ENVELOPE_RAY_MARGIN) + 1e-6
    d = np.stack([np.cos(angles), np.zeros_like(angles), np.sin(angles)], axis=1)
    o = np.stack([axis[0] + start * d[:, 0], heights, axis[1] + start * d[:, 2]], axis=1)
    scene = igl.embree.EmbreeIntersector()
    scene.init(np.asfortranarray(v, np.float32), np.asfortranarray(faces, np.int32), True)
    o32, d32 = o.astype(np.float32), (-d).astype(np.float32)
    t = np.full(len(o), np.inf)
    for k in range(len(o)):  # about 1 microsecond a ray: the loop is not the cost
        face, tk, _, _ = scene.intersectRay_first(o32[k], d32[k], 0.0, start)
        if face >= 0:
            t[k] = tk
    hit = np.isfinite(t) & (t < start)
    t = np.where(hit, t, 0.0)
    return o - d * t[:, None], hit


def radial_envelope(
    vertices: np.ndarray,
    faces: np.ndarray,
    num_vertices: int,
    *,
    min_component_fraction: float = 0.05,
) -> tuple[np.ndarray, np.ndarray]:
    """The outer radial envelope of a garment as one open triangle surface.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int64
    num_vertices : int
        About how many grid vertices to use (cells are roughly square).
    min_component_fraction : float
        Envelope islands smaller than this fraction of the largest are dropped.

    Returns
    -------
    vertices : (Ve, 3) float64, faces : (Fe, 3) int64
        Counter-clockwise seen from outside (normals point away from the axis).
    """
    v = np.asarray(vertices, np.float64)
    axis = garment_axis(v, faces)
    ymin, ymax = float(v[:, 1].min()), float(v[:, 1].max())
    height = max(ymax - ymin, 1e-9)
    a = face_areas(v, faces)
    c = v[faces].mean(axis=1)
    mean_r = float(
        (np.hypot(c[:, 0] - axis[0], c[:, 2] - axis[1]) * a).sum() / max(a.sum(), 1e-300)
    )
    circ = 2 * math.pi * max(mean_r, 1e-3 * height)
    cell = math.sqrt(circ * height / max(num_vertices, 64))
    n_ang = max(16, round(circ / cell))
    n_y = max(4, round(height / cell) + 1)
    ys = ymin + height * (np.arange(n_y) + 0.5) / n_y
    th = 2 * math.pi * np.arange(n_ang) / n_ang
    yy, tt = np.meshgrid(ys, th, indexing="ij")
    pts, hit = cast_radial(v, faces, yy.ravel(), tt.ravel(), axis)
    hit = hit.reshape(n_y, n_ang)

    idx = np.arange(n_y * n_ang).reshape(n_y, n_ang)
    # Quad corners in a cyclic order whose consecutive triples face outward:
    # (j, i) -> (j+1, i) -> (j+1, i+1) -> (j, i+1).
    q = np.stack(
        [idx[:-1], idx[1:], np.roll(idx[1:], -1, axis=1), np.roll(idx[:-1], -1, axis=1)], axis=-1
    ).reshape(-1, 4)
    ok = hit.ravel()[q]
    n_ok = ok.sum(1)
    full = q[n_ok == 4]
    tris = [full[:, [0, 1, 3]], full[:, [1, 2, 3]]]
    three = q[n_ok == 3]
    missing = np.argmin(ok[n_ok == 3], axis=1)
    for m in range(4):
        sel = three[missing == m]
        order = [(m + 1) % 4, (m + 2) % 4, (m + 3) % 4]
        tris.append(sel[:, order])
    f = np.concatenate(tris).astype(np.int64)
    if len(f) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    ev, ef, _ = compact(pts, f)
    ev, ef, _ = drop_small_components(ev, ef, min_component_fraction)
    ev = _snap_boundary(ev, ef, v, faces, 1.5 * max(cell, height / n_y))
    # Snapping can land neighbours on one point: merge them and drop the collapsed triangles.
    mesh, _ = validate_mesh(ev, ef)
    return mesh.vertices.astype(np.float64), mesh.faces


def _snap_boundary(
    ev: np.ndarray, ef: np.ndarray, v: np.ndarray, f: np.ndarray, reach: float
) -> np.ndarray:
    """Move the envelope's boundary vertices onto the garment's boundary (waist, hem) when one is
    within ``reach``, else onto the nearest garment surface point."""
    import igl
    from scipy.spatial import cKDTree

    edges, counts = edge_counts(ef)
    bv = np.unique(edges[counts == 1])
    if len(bv) == 0:
        return ev
    ev = ev.copy()
    tedges, tcounts = edge_counts(f)
    tb = tedges[tcounts == 1]
    snapped = np.zeros(len(bv), bool)
    if len(tb):
        # Dense samples along the garment's boundary edges.
        seg = v[tb[:, 1]] - v[tb[:, 0]]
        length = np.linalg.norm(seg, axis=1)
        step = max(reach / 8, 1e-9)
        n = np.maximum(1, np.ceil(length / step).astype(int))
        rep = np.repeat(np.arange(len(tb)), n)
        frac = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
        samples = v[tb[rep, 0]] + seg[rep] * frac[:, None]
        dist, near = cKDTree(samples).query(ev[bv])
        snapped = dist <= reach
        ev[bv[snapped]] = samples[near[snapped]]
    rest = bv[~snapped]
    if len(rest):
        _, _, closest = igl.point_mesh_squared_distance(
            ev[rest], np.ascontiguousarray(v), np.ascontiguousarray(f, np.int64)
        )
        ev[rest] = closest
    return ev


def encloses_axis(
    vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, axis: np.ndarray
) -> np.ndarray:
    """For each component label, whether the part goes around the vertical axis.

    A part encloses the axis when its vertices cover at least ``ENCLOSE_COVERAGE`` of
    ``ENCLOSE_BINS`` equal azimuth sectors: skirt layers, bodices, waistbands and sashes do;
    straps, sleeves, bows and strings do not.

    Parameters
    ----------
    vertices : (V, 3) float, faces : (F, 3) int, labels : (F,) int component of each face,
    axis : (2,) float (x, z) of the axis

    Returns
    -------
    (labels.max() + 1,) bool
    """
    v = np.asarray(vertices, np.float64)
    n = int(labels.max()) + 1 if len(labels) else 0
    vert_label = np.full(len(v), -1, np.int64)
    vert_label[faces.ravel()] = np.repeat(labels, 3)
    used = vert_label >= 0
    ang = np.arctan2(v[used, 2] - axis[1], v[used, 0] - axis[0])
    sector = ((ang + math.pi) / (2 * math.pi) * ENCLOSE_BINS).astype(np.int64) % ENCLOSE_BINS
    hit = np.zeros((n, ENCLOSE_BINS), bool)
    hit[vert_label[used], sector] = True
    return hit.mean(axis=1) >= ENCLOSE_COVERAGE


def covered_fraction(
    vertices: np.ndarray, faces: np.ndarray, axis: np.ndarray, samples: int = 0, seed: int = 0
) -> float:
    """Fraction of the area with more cloth outside it: the share of (sampled) faces whose
    horizontal ray away from the vertical axis, from the face's centre, meets the garment again.

    A surface star-shaped about the axis (one layer: a dress, a top, a skirt with a slit, however
    deep its folds) covers none of itself; stacked layers, linings, pleats folded under and the
    torso under a sleeve are covered, however small the gap between them.

    Parameters
    ----------
    vertices : (V, 3) float, faces : (F, 3) int, axis : (2,) float (x, z) of the axis
    samples : faces to test (drawn by area with ``seed``); 0 tests every face

    Returns
    -------
    float in [0, 1], area-weighted
    """
    import igl.embree

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    if len(f) == 0:
        return 0.0
    area = face_areas(v, f)
    if samples and len(f) > samples:
        rng = np.random.default_rng(seed)
        pick = rng.choice(len(f), samples, replace=False)
        f_test, weight = f[pick], area[pick]
    else:
        f_test, weight = f, area
    centre = v[f_test].mean(axis=1)
    out = centre - [axis[0], 0.0, axis[1]]
    out[:, 1] = 0.0
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    # Start a hair outside the face so that its own triangle is not the first hit.
    eps = 1e-5 * diag
    scene = igl.embree.EmbreeIntersector()
    scene.init(np.asfortranarray(v, np.float32), np.asfortranarray(f, np.int32), True)
    o32 = (centre + eps * out).astype(np.float32)
    d32 = out.astype(np.float32)
    covered = np.zeros(len(f_test), bool)
    for k in range(len(f_test)):
        face, _, _, _ = scene.intersectRay_first(o32[k], d32[k], 0.0, 2 * diag)
        covered[k] = face >= 0
    return float(weight[covered].sum() / max(weight.sum(), 1e-300))


def envelope_error(
    target_vertices: np.ndarray,
    target_faces: np.ndarray,
    envelope_vertices: np.ndarray,
    envelope_faces: np.ndarray,
    hidden_beyond: float,
) -> dict:
    """How well the envelope explains the garment.

    Returns a dict with

    - ``max_m``: the largest distance (metres) from a target vertex to the envelope;
    - ``hidden_inward``: the fraction of the target's area hidden behind the envelope (farther
      than ``hidden_beyond``) *and facing the axis*, such as the inner side of a sleeve
      (stacked skirt layers hide too, but face outward);
    - ``curtain``: the fraction of the envelope's area made of "curtains", triangles that
      bridge a radial jump larger than ``hidden_beyond`` sideways (normal within
      ``acos(CURTAIN_COS)`` of the azimuth direction): what spans the gap between a sleeve and
      the torso below it. Tier steps of a layered skirt bridge jumps downwards instead.

    ``target_faces`` must be oriented (see ``orient_consistently``).
    """
    import igl

    if len(envelope_faces) == 0:
        return {"max_m": math.inf, "hidden_inward": 1.0, "curtain": 1.0}
    ev = np.ascontiguousarray(envelope_vertices, np.float64)
    ef = np.ascontiguousarray(envelope_faces, np.int64)
    tv = np.asarray(target_vertices, np.float64)
    axis = garment_axis(tv, target_faces)

    def frames(tri):
        centre = tri.mean(axis=1)
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        radial = centre - [axis[0], 0.0, axis[1]]
        radial[:, 1] = 0.0
        radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-300)
        return centre, normal, radial

    # At most ENVELOPE_CHECK_SAMPLES vertices and faces (seeded): the test is a proportion.
    rng = np.random.default_rng(0)
    if len(tv) > ENVELOPE_CHECK_SAMPLES:
        tv_check = tv[rng.choice(len(tv), ENVELOPE_CHECK_SAMPLES, replace=False)]
    else:
        tv_check = tv
    tf = np.asarray(target_faces, np.int64)
    if len(tf) > ENVELOPE_CHECK_SAMPLES:
        tf = tf[rng.choice(len(tf), ENVELOPE_CHECK_SAMPLES, replace=False)]
    tri = tv[tf]
    centres, normal, radial = frames(tri)
    d2, _, _ = igl.point_mesh_squared_distance(np.concatenate([tv_check, centres]), ev, ef)
    d = np.sqrt(np.maximum(d2, 0))
    area = face_areas(tv, tf)
    inward = (normal * radial).sum(1) < -INWARD_COS
    hidden = (d[len(tv_check) :] > hidden_beyond) & inward

    etri = ev[ef]
    _, en, er = frames(etri)
    tangent = np.stack([-er[:, 2], np.zeros(len(er)), er[:, 0]], axis=1)
    r = np.hypot(etri[..., 0] - axis[0], etri[..., 2] - axis[1])
    jump = r.max(axis=1) - r.min(axis=1)
    curtain = (np.abs((en * tangent).sum(1)) > CURTAIN_COS) & (jump > hidden_beyond)
    earea = face_areas(ev, ef)
    return {
        "max_m": float(d.max()),
        "hidden_inward": float(area[hidden].sum() / max(area.sum(), 1e-300)),
        "curtain": float(earea[curtain].sum() / max(earea.sum(), 1e-300)),
    }
