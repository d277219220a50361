"""Fitting garments to the mannequin: where the body is, seen from a vertical axis.

Garments are built as surfaces around a vertical axis through the torso. This module answers
"how far out from that axis must the cloth stay at height ``y`` and angle ``theta``?" from the
rest-pose body mesh:

* the body's vertices are labelled by their nearest bone; arms, neck and head are left out
  (a skirt does not wrap the hanging arms, a bodice stops below the neck);
* a slab of the remaining body between two heights is enclosed by the 2D convex hull of the
  mesh's cuts at both heights and the vertices in between (exact for a triangle mesh; cloth
  spans concavities, e.g. between the legs);
* the hull is pushed out by a clearance and read back as a radius per angle.

Two profiles come from that: *local* (the slice at ``y`` only: fitted bodices) and *hanging*
(everything between ``y`` and a top height: skirts, which fall from the widest part above).

Angles: ``theta = 0`` faces the front (+Z), ``theta = pi/2`` the left side (+X); a point at
radius ``r`` is ``(r sin(theta), y, axis_z + r cos(theta))``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from core.body.mannequin import make_body
from core.body.shape import BodyShape, mannequin_skeleton
from core.numeric import smoothstep

from .surface import Folds, max_folds

#: Bones (named by their parent joint) whose vertices a garment does not wrap.
EXCLUDED_BONES = frozenset(
    {"LeftArm", "LeftForeArm", "LeftHand", "RightArm", "RightForeArm", "RightHand", "Neck", "Head"}
)
#: Angular samples of a precomputed profile (0.5 degree).
PROFILE_ANGLES = 720
#: Height step of a precomputed profile, metres.
PROFILE_STEP_M = 0.004


def body_mesh(shape: BodyShape | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The rest-pose mannequin mesh for ``shape`` (default ``BodyShape()``): ``make_body``.

    Returns
    -------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    """
    body = make_body(BodyShape() if shape is None else shape)
    return np.asarray(body.vertices, np.float64), np.asarray(body.faces, np.int64)


def bone_labels(vertices: np.ndarray, shape: BodyShape) -> tuple[np.ndarray, tuple[str, ...]]:
    """Nearest bone of every vertex.

    Parameters
    ----------
    vertices : (V, 3) float
    shape : the body shape the vertices belong to (its rest skeleton)

    Returns
    -------
    labels : (V,) int64
        Index into ``names``.
    names : tuple of str
        Bone names: the parent joint of each bone segment (end sites included).
    """
    skel = mannequin_skeleton(shape)
    pos = skel.rest_positions().astype(np.float64)
    starts, ends, names = [], [], []
    for j, p in enumerate(skel.parents):
        if p >= 0:
            starts.append(pos[p])
            ends.append(pos[j])
            names.append(skel.names[p])
        if np.any(skel.end_sites[j]):
            starts.append(pos[j])
            ends.append(pos[j] + skel.end_sites[j])
            names.append(skel.names[j])
    a, b = np.array(starts), np.array(ends)
    ab = b - a
    v = np.asarray(vertices, np.float64)[:, None, :]
    t = np.clip(np.einsum("vbk,bk->vb", v - a, ab) / np.einsum("bk,bk->b", ab, ab), 0.0, 1.0)
    d = np.linalg.norm(v - (a + t[..., None] * ab), axis=2)
    return np.argmin(d, axis=1), tuple(names)


@dataclass(frozen=True)
class BodyFit:
    """The parts of a rest-pose body that garments wrap, ready for radius queries.

    Attributes
    ----------
    vertices : (V, 3) float64
        The whole body mesh's vertices (for ray casts and clearance checks).
    faces : (F, 3) int64
    kept : (V,) bool
        Torso and leg vertices (arms, neck and head left out).
    arms : (V,) bool
        Arm and hand vertices.
    edges : (E, 2) int64
        Unique mesh edges between two kept vertices (what horizontal slices cut).
    axis_z : float
        Z of the vertical axis all radii are measured from (X is 0).
    shape : BodyShape
    """

    vertices: np.ndarray
    faces: np.ndarray
    kept: np.ndarray
    arms: np.ndarray
    edges: np.ndarray
    axis_z: float
    shape: BodyShape

    def slice_points(self, y: float, edges: np.ndarray | None = None) -> np.ndarray:
        """Where the kept body surface crosses height ``y``: (N, 2) float64 (x, z - axis_z).

        ``edges`` (E, 2) int64: a subset of :attr:`edges` to cut (default all).
        """
        e = self.edges if edges is None else edges
        a, b = self.vertices[e[:, 0]], self.vertices[e[:, 1]]
        cross = ((a[:, 1] - y) * (b[:, 1] - y) <= 0) & (a[:, 1] != b[:, 1])
        a, b = a[cross], b[cross]
        t = (y - a[:, 1]) / (b[:, 1] - a[:, 1])
        p = a + t[:, None] * (b - a)
        return p[:, [0, 2]] - [0.0, self.axis_z]

    def profile(
        self, y_top: float, y_bottom: float, clearance: float, hanging: bool
    ) -> RadialProfile:
        """Precomputed radius the cloth must keep, between ``y_bottom`` and ``y_top``.

        ``hanging``: each sample covers the slab from one step below it up to ``y_top``
        (skirts fall from the widest part above); otherwise the slab one step either side
        (fitted parts). Then :class:`RadialProfile`'s interpolation covers every height.
        """
        step = PROFILE_STEP_M
        ys = np.arange(y_top + step, y_bottom - 2 * step, -step)
        thetas = np.linspace(0, 2 * np.pi, PROFILE_ANGLES, endpoint=False)
        radius = np.zeros((len(ys), len(thetas)))
        # Only edges that reach into the profile's heights can be cut; cut each height once.
        ey = self.vertices[self.edges, 1]
        near = (ey.max(axis=1) >= ys[-1] - step) & (ey.min(axis=1) <= ys[0] + step)
        edges = self.edges[near]
        cut_y = np.concatenate([[ys[0] + step], ys, [ys[-1] - step]])
        cuts = [self.slice_points(float(c), edges) for c in cut_y]
        v = self.vertices[self.kept]
        v = v[(v[:, 1] >= cut_y[-1]) & (v[:, 1] <= cut_y[0])]
        order = np.argsort(-v[:, 1])
        v_y, v_xz = v[order, 1], v[order][:, [0, 2]] - [0.0, self.axis_z]

        def between(hi: float, lo: float) -> np.ndarray:
            i0, i1 = np.searchsorted(-v_y, [-hi, -lo], side="right")
            return v_xz[i0:i1]

        hull_pts = np.zeros((0, 2))
        for i, yi in enumerate(ys):
            # cut_y[i], cut_y[i + 1], cut_y[i + 2] are yi + step, yi, yi - step.
            if hanging:
                # The slab [yi - step, y_top] is the previous one plus a thin slab below.
                slab = [hull_pts, cuts[i + 1], cuts[i + 2], between(yi, yi - step)]
                if i == 0:
                    slab += [cuts[0], between(yi + step, yi)]
                hull_pts = _hull_points(np.concatenate(slab))
                radius[i] = _hull_radius(hull_pts, thetas, clearance)
            else:
                slab = [cuts[i], cuts[i + 1], cuts[i + 2], between(yi + step, yi - step)]
                radius[i] = _hull_radius(np.concatenate(slab), thetas, clearance)
        return RadialProfile(ys=ys, radius=_closing(radius, 2, 6))


@dataclass(frozen=True)
class RadialProfile:
    """Radius the cloth must keep per height and angle.

    Attributes
    ----------
    ys : (H,) float64
        Heights, descending, ``PROFILE_STEP_M`` apart.
    radius : (H, PROFILE_ANGLES) float64
        Radius at each height and angle ``2 pi k / PROFILE_ANGLES``.
    """

    ys: np.ndarray
    radius: np.ndarray

    def __call__(self, y: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Radius at heights ``y`` and angles ``theta`` (broadcast together): float64.

        Linear in height and angle. Each sample covers the slab one step either side of it,
        so both samples around a height cover it and so does any mix of them. Heights outside
        the profile take the nearest end.
        """
        y, theta = np.broadcast_arrays(np.asarray(y, np.float64), np.asarray(theta, np.float64))
        h = len(self.ys)
        # ys descend: index of the sample just above y.
        f = (self.ys[0] - y) / PROFILE_STEP_M
        i0 = np.clip(np.floor(f).astype(np.int64), 0, h - 1)
        i1 = np.clip(i0 + 1, 0, h - 1)
        a = np.mod(theta, 2 * np.pi) / (2 * np.pi) * PROFILE_ANGLES
        j0 = np.floor(a).astype(np.int64) % PROFILE_ANGLES
        j1 = (j0 + 1) % PROFILE_ANGLES
        w = a - np.floor(a)
        r = self.radius

        def at(i):
            return (1 - w) * r[i, j0] + w * r[i, j1]

        fy = np.clip(f - i0, 0.0, 1.0)
        return (1 - fy) * at(i0) + fy * at(i1)


@functools.lru_cache(maxsize=8)
def body_fit(shape: BodyShape | None = None) -> BodyFit:
    """:class:`BodyFit` for ``shape`` (default ``BodyShape()``; cached: shapes are frozen)."""
    shape = BodyShape() if shape is None else shape
    v, f = body_mesh(shape)
    labels, names = bone_labels(v, shape)
    excluded = np.array([n in EXCLUDED_BONES for n in names])
    kept = ~excluded[labels]
    arm_bone = np.array([n.endswith(("Arm", "ForeArm", "Hand")) for n in names])
    arms = arm_bone[labels]
    edges = np.unique(np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    edges = edges[kept[edges].all(axis=1)]
    skel = mannequin_skeleton(shape)
    pos = skel.rest_positions()
    axis_z = float(np.mean([pos[skel.index(n)][2] for n in ("Hips", "Spine", "Spine1")]))
    return BodyFit(
        vertices=v, faces=f, kept=kept, arms=arms, edges=edges, axis_z=axis_z, shape=shape
    )


def flared_tube(
    fit: BodyFit,
    y_top: float,
    y_waist: float,
    y_hem: float,
    clearance: float,
    ease: float,
    flare: float,
    fold_depth: float,
    folds: int,
    res: float,
    rng: np.random.Generator,
):
    """A one-piece garment's radius: fitted above the waist, hanging below it, flaring and
    folding towards the hem (a dress, a long top).

    Parameters
    ----------
    fit : BodyFit
    y_top, y_waist, y_hem : float
        Heights (metres) of the top, the waist and the hem.
    clearance, ease, flare, fold_depth : float
        Metres: gap kept from the body, extra width everywhere, extra radius at the hem, depth
        of the folds at the hem.
    folds : int
        Number of folds asked for (fewer when the hem is too short for them at ``res``).
    res : float
        Target edge length (metres).
    rng : numpy Generator
        Seeds the folds' irregularity (drawn here, in a fixed order).

    Returns
    -------
    local : RadialProfile
        The fitted (slice) profile above the waist.
    body : callable ``(y, theta) -> r``
        The radius the cloth must keep: ``local`` above the waist, hanging below.
    radius : callable ``(y, theta, bound=False) -> r``
        The garment's radius; ``bound=True`` gives its outer bound (folds at full depth).
        ``y`` and ``theta`` broadcast together (float arrays).
    """
    local = fit.profile(y_top + 0.01, y_waist - 0.01, clearance, hanging=False)
    hang = fit.profile(y_waist, y_hem - 0.03, clearance, hanging=True)

    def body(y, theta):
        return np.where(y >= y_waist, local(y, theta), hang(y, theta))

    angles = np.linspace(0, 2 * np.pi, 256, endpoint=False)
    perim = 2 * np.pi * (float(np.mean(hang(y_hem, angles))) + flare)
    fold = Folds.make(min(folds, max_folds(perim, res)), rng, twist=rng.normal() * 3)
    length = y_waist - y_hem

    def radius(y, theta, bound=False):
        x = np.clip((y_waist - y) / length, 0.0, 1.0)
        r = body(y, theta) + ease + flare * x**1.4
        amp = fold_depth * smoothstep(x / 0.8)
        return r + (amp if bound else amp * fold(theta, y_waist - y))

    return local, body, radius


def _closing(radius: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Smooth (H, A) radii without lowering any: the moving average of the moving maximum.

    Windows of ``2 rows + 1`` heights (clamped at the ends) and ``2 cols + 1`` angles
    (periodic). Every output is at least its input, since the input sample lies in the
    maximum window of every sample its average window covers.
    """
    from scipy.ndimage import maximum_filter, uniform_filter

    size = (2 * rows + 1, 2 * cols + 1)
    m = maximum_filter(radius, size=size, mode=("nearest", "wrap"))
    return np.maximum(uniform_filter(m, size=size, mode=("nearest", "wrap")), radius)


def _hull_points(pts: np.ndarray) -> np.ndarray:
    """Vertices of the 2D convex hull of ``pts`` (N, 2), counter-clockwise; input if too few."""
    from scipy.spatial import ConvexHull, QhullError

    if len(pts) < 3:
        return pts
    try:
        return pts[ConvexHull(pts).vertices]
    except QhullError:
        return pts


def _hull_radius(pts: np.ndarray, thetas: np.ndarray, clearance: float) -> np.ndarray:
    """Radius per angle of the hull of ``pts`` (N, 2) (x, z), its edges moved out by clearance.

    The origin must lie inside the hull (true for slices of the torso and the hips); where it
    does not, the hull's farthest point stands in. Mitred offset corners are conservative.
    """
    thetas = np.asarray(thetas, np.float64)
    if len(pts) < 3:
        return np.zeros(len(thetas))
    hull = _hull_points(pts)
    if len(hull) < 3:
        return np.full(len(thetas), np.linalg.norm(pts, axis=1).max() + clearance)
    p0, p1 = hull, np.roll(hull, -1, axis=0)
    d = p1 - p0
    # (x, z) with theta measured from +z towards +x; the hull is ccw in (x, z).
    normal = np.stack([d[:, 1], -d[:, 0]], axis=1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    c = np.einsum("kd,kd->k", normal, p0)
    if (c <= 0).any():
        # ConvexHull orders 2D hulls counter-clockwise in (x, z); flip if that ever changes.
        normal, c = -normal, -c
    if (c <= 0).any():  # origin outside the hull
        return np.full(len(thetas), np.linalg.norm(hull, axis=1).max() + clearance)
    direction = np.stack([np.sin(thetas), np.cos(thetas)], axis=1)
    nd = direction @ normal.T  # (A, K)
    with np.errstate(divide="ignore"):
        dist = np.where(nd > 1e-9, (c + clearance) / nd, np.inf)
    return dist.min(axis=1)
