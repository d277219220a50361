"""Synthetic garment-like meshes for tests and benchmarks of the proxy stage.

They stand in for garments exported from other tools (no downloads here): parametric tubes
with waist and hem boundaries, stacked layers, hem ruffles, pleats, small separate parts (bow,
strings), and a T-shirt made of several overlapping tubes. All in metres, Y up, outward faces.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np


def tube(
    radius: Callable[[np.ndarray, np.ndarray], np.ndarray],
    start: np.ndarray,
    end: np.ndarray,
    n_around: int,
    n_along: int,
    *,
    closed: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """An open (or capped) tube from ``start`` to ``end``.

    ``radius(theta, s)`` gives the radius at angle ``theta`` (radians) and arc fraction ``s``
    in [0, 1] from ``start``; both are (n_along, n_around) arrays. Returns ``(V, 3)`` float64
    vertices and ``(F, 3)`` int64 faces, counter-clockwise seen from outside.
    """
    start, end = np.asarray(start, float), np.asarray(end, float)
    axis = end - start
    length = np.linalg.norm(axis)
    w = axis / length
    helper = np.array([0.0, 0.0, 1.0]) if abs(w[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(w, helper)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    s = np.linspace(0, 1, n_along)
    th = 2 * math.pi * np.arange(n_around) / n_around
    ss, tt = np.meshgrid(s, th, indexing="ij")
    r = radius(tt, ss)
    pts = (
        start
        + ss[..., None] * axis
        + r[..., None] * (np.cos(tt)[..., None] * u + np.sin(tt)[..., None] * v)
    ).reshape(-1, 3)
    idx = np.arange(n_along * n_around).reshape(n_along, n_around)
    a, b = idx[:-1], np.roll(idx[:-1], -1, axis=1)
    c, d = idx[1:], np.roll(idx[1:], -1, axis=1)
    f = np.concatenate(
        [np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)]
    )
    # u x v = w: going around is counter-clockwise about w, so (a, b, d) faces outward when
    # the tube runs along w.
    if closed:
        caps = []
        for ring, centre, flip in ((idx[0], start, True), (idx[-1], end, False)):
            ci = len(pts) + len(caps)
            caps.append(centre)
            nxt = np.roll(ring, -1)
            tri = np.stack([np.full_like(ring, ci), nxt, ring], -1)
            f = np.concatenate([f, tri[:, ::-1] if not flip else tri])
        pts = np.concatenate([pts, np.array(caps)])
    return pts, f.astype(np.int64)


def ring_grid(heights: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rings around the vertical (Y) axis joined into an open tube.

    Parameters
    ----------
    heights : (R,) float
        Height of each ring, top first.
    radii : (R, A) float
        Radius of ring ``j`` at angle ``2 pi i / A`` (0 faces +Z, pi/2 faces +X).

    Returns
    -------
    vertices : (R * A, 3) float64
        Ring by ring: ``(r sin a, y, r cos a)``.
    faces : (2 (R - 1) A, 3) int64
        Two triangles per quad, ring by ring, outward for rings going down.
    """
    heights = np.asarray(heights, np.float64)
    radii = np.asarray(radii, np.float64)
    rings, around = radii.shape
    a = 2 * np.pi * np.arange(around) / around
    verts = np.stack(
        [radii * np.sin(a), np.broadcast_to(heights[:, None], radii.shape), radii * np.cos(a)], -1
    ).reshape(-1, 3)
    return verts, ring_faces(rings, around)


def ring_faces(rings: int, around: int) -> np.ndarray:
    """The triangles of :func:`ring_grid`'s layout (vertex ``j * around + i``: ring j, angle i),
    (2 (rings - 1) around, 3) int64: two per quad, ring by ring, closed around."""
    j, i = np.meshgrid(np.arange(rings - 1), np.arange(around), indexing="ij")
    p, q = j * around + i, j * around + (i + 1) % around
    faces = np.stack(
        [np.stack([p, p + around, q], -1), np.stack([q, p + around, q + around], -1)], -2
    )
    return faces.reshape(-1, 3).astype(np.int64)


def skirt_tube(
    *,
    waist_y: float = 1.0,
    length: float = 0.6,
    waist_r: float = 0.14,
    hem_r: float = 0.33,
    n_around: int = 128,
    n_along: int = 40,
    folds: int = 0,
    fold_depth: float = 0.0,
    flare_length: float | None = None,
    flare_power: float = 0.8,
    fold_power: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """One skirt layer from the waist (top loop) down to the hem (bottom loop), with ``folds``
    vertical pleats of ``fold_depth`` metres growing from the waist to the hem. The radius
    reaches ``hem_r`` at ``flare_length`` below the waist (default ``length``), so layers of
    different lengths with the same flare follow each other at a constant gap.

    At a fraction ``s`` of the way down, the radius is ``waist_r + (hem_r - waist_r) *
    drop**flare_power`` (``drop = s * length / flare_length``; 1: a cone frustum, below 1: a
    bell) and the pleats are ``fold_depth * s**fold_power`` deep."""
    flare = length if flare_length is None else flare_length

    def radius(th, s):
        drop = s * length / flare
        pleat = fold_depth * s**fold_power * np.sin(folds * th)
        return waist_r + (hem_r - waist_r) * drop**flare_power + pleat

    return tube(radius, [0, waist_y, 0], [0, waist_y - length, 0], n_around, n_along)


def _merge(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    vs, fs, off = [], [], 0
    for v, f in parts:
        vs.append(v)
        fs.append(f + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def bow(
    centre, size: float = 0.04, n: int = 12, string_end_z: float = 0.28
) -> list[tuple[np.ndarray, np.ndarray]]:
    """A bow: two loops and two strings hanging 25 cm down to ``string_end_z`` in front, each
    its own component."""
    c = np.asarray(centre, float)
    parts = []
    for side in (-1, 1):
        loop = tube(
            lambda th, s: size * 0.25 + 0 * th,
            c + [side * size * 0.1, 0, 0],
            c + [side * size, 0, 0],
            n,
            6,
            closed=True,
        )
        parts.append(loop)
        string = tube(
            lambda th, s: 0.0015 + 0 * th,
            c + [side * size * 0.2, -0.01, 0.005],
            [c[0] + side * size * 0.6, c[1] - 0.25, string_end_z],
            6,
            20,
        )
        parts.append(string)
    return parts


def layered_skirt(
    *,
    layers: int = 3,
    gap: float = 0.012,
    ruffle: bool = True,
    with_bow: bool = True,
    n_around: int = 160,
    n_along: int = 48,
) -> tuple[np.ndarray, np.ndarray]:
    """A tiered skirt: ``layers`` stacked layers (outer ones shorter and ``gap`` wider), a
    ruffle around the outer hem, and a bow with strings at the front waist. Several components,
    no UVs. Waist at y = 1.0 m, longest hem at y = 0.35 m."""
    parts = []
    for k in range(layers):  # k = 0 is the outermost (and shortest) layer
        parts.append(
            skirt_tube(
                length=0.65 - 0.1 * (layers - 1 - k),
                waist_r=0.14 + 0.002 * (layers - 1 - k),
                hem_r=0.33 + gap * (layers - 1 - k),
                flare_length=0.65,
                n_around=n_around,
                n_along=n_along,
            )
        )
    if ruffle:
        outer_len = 0.65 - 0.1 * (layers - 1)
        r0 = 0.14 + 0.002 * (layers - 1) + (0.19 + gap * (layers - 1)) * (outer_len / 0.65) ** 0.8
        y0 = 1.0 - outer_len
        parts.append(
            tube(
                lambda th, s: r0 + 0.01 + 0.012 * np.sin(60 * th) * s + 0.03 * s,
                [0, y0 + 0.02, 0],
                [0, y0 - 0.05, 0],
                n_around * 2,
                8,
            )
        )
    if with_bow:
        # Strings end just outside the outer layer, 25 cm below the bow.
        outer_r = 0.14 + 0.002 * (layers - 1) + (0.19 + gap * (layers - 1)) * (0.28 / 0.65) ** 0.8
        parts += bow([0.0, 0.97, 0.16], string_end_z=outer_r + 0.01)
    return _merge(parts)


def tshirt(
    *, n_around: int = 64, n_along: int = 40, closed: bool = False, one_piece: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """A T-shirt as three overlapping tubes (torso, two sleeves at 45 degrees down), plus a
    small pocket patch: four components, no UVs. ``closed`` caps every tube (watertight parts).
    ``one_piece`` joins each sleeve to the torso with a seam triangle, so the shirt is one
    connected part, as sewn-in sleeves are."""
    parts = [
        tube(
            lambda th, s: 0.16 + 0.02 * np.cos(2 * th) ** 2 + 0 * s,
            [0, 1.45, 0],
            [0, 0.95, 0],
            n_around * 2,
            n_along,
            closed=closed,
        )
    ]
    for side in (-1, 1):
        sh = np.array([side * 0.16, 1.38, 0.0])
        d = np.array([side * math.cos(math.pi / 4), -math.sin(math.pi / 4), 0.0])
        parts.append(
            tube(
                lambda th, s: 0.065 - 0.015 * s + 0 * th,
                sh - 0.02 * d,
                sh + 0.22 * d,
                n_around,
                n_along // 2,
                closed=closed,
            )
        )
    # A pocket: a small patch 3 mm outside the chest, its own component.
    ang = np.linspace(math.pi / 2 - 0.55, math.pi / 2 - 0.05, 8)
    aa, yy = np.meshgrid(ang, np.linspace(1.25, 1.35, 8), indexing="ij")
    rr = 0.163 + 0.02 * np.cos(2 * aa) ** 2
    pv = np.stack([(rr * np.cos(aa)).ravel(), yy.ravel(), (rr * np.sin(aa)).ravel()], 1)
    idx = np.arange(64).reshape(8, 8)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    pf = np.concatenate(
        [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    )
    parts.append((pv, pf))
    v, f = _merge(parts)
    if one_piece:
        sizes = np.cumsum([0] + [len(p[0]) for p in parts])
        torso = np.arange(sizes[0], sizes[1])
        seams = []
        for k in (1, 2):  # first ring of each sleeve
            ring = np.arange(sizes[k], sizes[k] + n_around)
            d = np.linalg.norm(v[ring][:, None] - v[torso][None], axis=2)
            i, j = np.unravel_index(np.argmin(d), d.shape)
            seams.append([torso[j], ring[(i + 1) % n_around], ring[i]])
        f = np.concatenate([f, np.array(seams, np.int64)])
    return v, f


def split_uv_seams(
    vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A garment as a pattern-making tool exports it with UVs: a front and a back piece, each
    its own UV chart, so every vertex on a seam between them is written twice (same position,
    two UVs) and the file's mesh is cut open along the seams.

    Parameters
    ----------
    vertices : (V, 3) float, faces : (F, 3) int
        The welded garment (Y up, front towards +Z).

    Returns
    -------
    vertices : (V', 3) float64, V' > V; faces : (F, 3) int64; uvs : (V', 2) float64 in [0, 1]
        Front piece on the left half of the texture, back piece on the right half.
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    piece = (v[f].mean(axis=1)[:, 2] < np.median(v[:, 2])).astype(np.int64)  # 0 front, 1 back
    key = f * 2 + piece[:, None]
    uniq, inverse = np.unique(key.ravel(), return_inverse=True)
    src, side = uniq // 2, uniq % 2
    lo, hi = v.min(axis=0), v.max(axis=0)
    span = max(hi[0] - lo[0], hi[1] - lo[1], 1e-12)
    u = (v[src, 0] - lo[0]) / span
    u = np.where(side == 0, u, 1.0 - u)  # the back piece seen from behind
    uvs = np.stack([0.5 * side + 0.49 * u, (v[src, 1] - lo[1]) / span], axis=1)
    return v[src], inverse.reshape(-1, 3).astype(np.int64), uvs
