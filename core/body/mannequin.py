"""The parametric mannequin: a smooth, closed body mesh on the mannequin skeleton.

The body is an implicit surface, a smooth union of girth-driven primitives laid along the
bones of :func:`core.body.shape.mannequin_skeleton`:

* the torso is a generalised elliptic cylinder whose cross-section (half-width ``a(y)``,
  half-depth ``b(y)``) is interpolated (monotone cubic) between key levels: hip, waist and chest
  girths drive the ellipses there, the shoulder width drives the top; its ends are rounded;
* neck, arms, legs are tapered capsules, the head and hands ellipsoids, the feet capsules.

Before meshing, the girths of the field are measured at the hip, waist and chest levels (the
convex hull of the cross-section, like a tape measure) and the torso keys are rescaled until
they match the requested girths. The field is then sampled on a grid (each primitive only in
its bounding box), meshed by marching cubes (libigl), reduced to the largest component,
decimated (fast-simplification, quadric error) to about ``resolution`` vertices, cleared of
valence-3 vertices, and relaxed: vertices slide within the surface towards their neighbours'
mean and are projected back onto the implicit surface, so the triangles are even and every
vertex lies on the surface.

Arms and legs are blended onto the trunk one chain at a time and united by a hard minimum, and
the limbs keep a gap of a few grid cells between them (thighs, calves, feet), so the mesh is a
sphere topologically (genus 0) for all but the most extreme shapes (very narrow shoulders on a
tall body put the arms into the torso).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from core.body.colliders import BodyCapsules, body_capsules
from core.body.shape import (
    CHEST_LEVEL,
    HIP_LEVEL,
    TORSO_BOTTOM,
    TORSO_TOP,
    WAIST_LEVEL,
    BodyShape,
    mannequin_skeleton,
    torso_keys,
)
from core.body.skinning import skinning_weights
from core.errors import InputError
from core.mesh import Mesh
from core.skeleton import Skeleton

#: Default and allowed target vertex counts.
DEFAULT_RESOLUTION = 9000
RESOLUTION_LIMITS = (2000, 40000)
#: Tangential relaxation passes after decimation (evens out the triangles).
RELAX_ITERATIONS = 8


@dataclass(frozen=True)
class Body:
    """A mannequin body: its rest mesh on its rest skeleton, skinned.

    Attributes
    ----------
    shape : BodyShape
        The parameters it was built from.
    skeleton : Skeleton
        ``mannequin_skeleton(shape)``: 20 joints (root Hips, then the 19 canonical ones).
    vertices : (V, 3) float32
        Rest (A-pose) positions, metres, Y up, facing +Z.
    faces : (F, 3) int64
        Counter-clockwise triangles, normals outwards; closed and manifold.
    weights : (V, J) float32
        Linear-blend skinning weights: non-negative, rows sum to 1, at most 4 non-zeros per row.
    capsules : core.body.colliders.BodyCapsules
        The collision capsules the cloth simulation uses for this shape
        (:func:`core.body.colliders.body_capsules`).
    levels : dict of str -> float
        Heights (metres) of the ``"hip"``, ``"waist"`` and ``"chest"`` girth measurements.

    The arrays are read-only: bodies are cached and shared.
    """

    shape: BodyShape
    skeleton: Skeleton
    vertices: np.ndarray
    faces: np.ndarray
    weights: np.ndarray
    capsules: BodyCapsules
    levels: dict

    @property
    def num_vertices(self) -> int:
        return len(self.vertices)

    @property
    def mesh(self):
        """The rest mesh as a :class:`core.mesh.Mesh`."""
        return Mesh(self.vertices, self.faces)

    def girth(self, level: str) -> float:
        """Measured girth (metres) of the rest mesh at ``"hip"``, ``"waist"`` or ``"chest"``."""
        if level not in self.levels:
            raise InputError(f"unknown girth level {level!r}; use one of {sorted(self.levels)}")
        return girth_at(self.vertices, self.faces, self.levels[level])


def make_body(shape: BodyShape | None = None, resolution: int = DEFAULT_RESOLUTION) -> Body:
    """Build (or fetch from the in-memory cache) the skinned mannequin for ``shape``.

    Parameters
    ----------
    shape : BodyShape, default ``BodyShape()``
    resolution : int
        Target number of vertices, in ``RESOLUTION_LIMITS``; the result is within a few
        percent of it.

    Returns
    -------
    Body
    """
    shape = BodyShape() if shape is None else shape
    if not isinstance(shape, BodyShape):
        raise InputError(f"shape must be a BodyShape, got {type(shape).__name__}")
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)):
        raise InputError(f"resolution must be an integer vertex count, got {resolution!r}")
    lo, hi = RESOLUTION_LIMITS
    if not lo <= resolution <= hi:
        raise InputError(f"resolution {resolution} is outside [{lo}, {hi}]")
    return _make_body_cached(shape, int(resolution))


@functools.lru_cache(maxsize=16)
def _make_body_cached(shape: BodyShape, resolution: int) -> Body:
    skeleton = mannequin_skeleton(shape)
    vertices, faces = body_mesh(shape, resolution)
    weights = skinning_weights(vertices, faces, skeleton)
    capsules = body_capsules(skeleton, shape)
    for a in (vertices, faces, weights):
        a.setflags(write=False)
    h = shape.height
    levels = {"hip": HIP_LEVEL * h, "waist": WAIST_LEVEL * h, "chest": CHEST_LEVEL * h}
    return Body(shape, skeleton, vertices, faces, weights, capsules, levels)


# --------------------------------------------------------------------------------------------
# The implicit body
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Prim:
    """One primitive of the implicit body: kind, parameters, blend radius, bounding box."""

    kind: str  # "capsule", "ellipsoid" or "torso"
    params: tuple
    blend: float
    lo: np.ndarray
    hi: np.ndarray


def _capsule(a, b, ra, rb, blend) -> _Prim:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    r = max(ra, rb)
    return _Prim("capsule", (a, b, ra, rb), blend, np.minimum(a, b) - r, np.maximum(a, b) + r)


def _ellipsoid(center, axes, semi, blend) -> _Prim:
    """``axes`` (3, 3): rows are the ellipsoid's unit axes; ``semi`` (3,): semi-axis lengths."""
    center, axes, semi = (np.asarray(x, np.float64) for x in (center, axes, semi))
    ext = np.sqrt(((axes * semi[:, None]) ** 2).sum(0))
    return _Prim("ellipsoid", (center, axes, semi), blend, center - ext, center + ext)


@dataclass(frozen=True)
class _TorsoProfile:
    """Key levels of the torso: heights (K,), half-widths (K,), half-depths (K,), centres (K,)."""

    y: np.ndarray
    a: np.ndarray
    b: np.ndarray
    zc: np.ndarray
    y0: float
    y1: float
    round_bottom: float
    round_top: float

    def sections(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Half-width, half-depth, z-centre at heights ``y`` (clipped to the torso)."""
        from scipy.interpolate import PchipInterpolator

        yc = np.clip(y, self.y0, self.y1)
        return tuple(PchipInterpolator(self.y, v)(yc) for v in (self.a, self.b, self.zc))


def _torso_profile(shape: BodyShape, scale: dict[str, float]) -> _TorsoProfile:
    """Torso key sections; ``scale`` multiplies the hip/waist/chest girths (the fit's knobs)."""
    h = shape.height
    ys, a, b, zc = torso_keys(shape, scale)
    b_bottom, b_top = b[0], b[-1]
    return _TorsoProfile(
        y=ys,
        a=a,
        b=b,
        zc=zc,
        y0=TORSO_BOTTOM * h,
        y1=TORSO_TOP * h,
        round_bottom=0.6 * min(b_bottom, a[0]),
        round_top=0.8 * min(b_top, a[-1]),
    )


def _primitives(shape: BodyShape, skeleton: Skeleton, torso: _TorsoProfile, min_r: float):
    """The primitives of the body: ``(base, chains)``.

    ``base`` (torso, neck, head, shoulders) is blended in order; each chain (an arm, a leg) is
    blended onto the base on its own and the results united by a hard minimum, so that the
    two thighs (or an arm and the torso side) never web together.
    """
    h, t = shape.height, shape.thickness
    p = skeleton.rest_positions().astype(np.float64)
    ix = skeleton.index
    end = skeleton.end_sites.astype(np.float64)

    def r(x: float) -> float:  # a limb radius: fraction of height, times build, not too thin
        return max(x * h * t, min_r)

    k_body, k_limb = 0.022 * h, 0.012 * h
    lo = np.array([-max(torso.a.max(), 1e-3), torso.y0, -torso.b.max() - 0.05 * h])
    lo[2] += torso.zc.min()
    hi = np.array([max(torso.a.max(), 1e-3), torso.y1, torso.b.max() + 0.05 * h])
    base = [_Prim("torso", (torso,), 0.0, lo, hi)]
    neck_r = r(0.032)
    neck_base = np.array([0.0, 0.80 * h, p[ix("Neck"), 2]])
    base.append(_capsule(neck_base, p[ix("Head")] + [0, 0.01 * h, 0], neck_r, 0.9 * neck_r, k_body))
    head_c = p[ix("Head")] + end[ix("Head")] * 0.5 + np.array([0.0, 0.0, 0.012 * h])
    head_semi = np.array([0.046 * h, 0.5 * end[ix("Head"), 1] + 0.004 * h, 0.056 * h])
    head_semi = np.maximum(head_semi, 1.05 * neck_r)
    base.append(_ellipsoid(head_c, np.eye(3), head_semi, 0.6 * k_body))
    chains = []
    for side in ("Left", "Right"):
        arm, fore, hand = p[ix(f"{side}Arm")], p[ix(f"{side}ForeArm")], p[ix(f"{side}Hand")]
        sx = 1.0 if side == "Left" else -1.0
        # Shoulder: a capsule from the base of the neck out to the arm joint (trapezius/deltoid).
        inner = np.array([sx * 0.04 * h, 0.80 * h, p[ix(f"{side}Arm"), 2]])
        base.append(_capsule(inner, arm, r(0.030), r(0.028), k_body))
        d = end[ix(f"{side}Hand")]
        length = np.linalg.norm(d)
        u = d / length
        n = np.cross(u, [0.0, 0.0, 1.0])
        n /= np.linalg.norm(n)
        axes = np.stack([u, n, np.cross(u, n)])
        semi = np.array([0.55 * length, r(0.0075), max(0.023 * h, r(0.0075))])
        chains.append(
            [
                _capsule(arm, fore, r(0.026), r(0.019), k_limb),
                _capsule(fore, hand, r(0.019), r(0.0125), k_limb),
                _ellipsoid(hand + 0.45 * d, axes, semi, 0.6 * k_limb),
            ]
        )
    for side in ("Left", "Right"):
        up, knee, foot = p[ix(f"{side}UpLeg")], p[ix(f"{side}Leg")], p[ix(f"{side}Foot")]
        half = abs(up[0])
        # Leave a gap between the thighs (and calves) of at least ~3 grid cells, or marching
        # cubes bridges them into handles.
        gap = 1.5 * min_r / 1.6
        thigh = max(min(r(0.050), 0.9 * half, half - gap), 0.6 * min_r)
        knee_r = max(min(r(0.030), thigh, abs(knee[0]) - gap), 0.6 * min_r)
        calf = knee + 0.3 * (foot - knee)
        calf_r = max(min(r(0.034), 0.9 * abs(calf[0]), abs(calf[0]) - gap), 0.6 * min_r)
        ankle_r = max(min(r(0.020), abs(foot[0]) - gap), 0.6 * min_r)
        toe = foot + end[ix(f"{side}Foot")]
        foot_r = max(min(0.021 * h, abs(foot[0]) - gap), 0.6 * min_r)
        heel = np.array([foot[0], foot_r, foot[2] - 0.028 * h])
        tip = np.array([toe[0], 0.85 * foot_r, toe[2] - 0.85 * foot_r])
        chains.append(
            [
                _capsule(up, knee, thigh, knee_r, k_body),
                _capsule(knee, calf, knee_r, calf_r, k_limb),
                _capsule(calf, foot, calf_r, ankle_r, k_limb),
                _capsule(foot, heel, ankle_r, foot_r, 0.5 * k_limb),
                _capsule(heel, tip, foot_r, 0.85 * foot_r, 0.5 * k_limb),
            ]
        )
    return base, chains


def _eval_prim(prim: _Prim, x, y, z):
    """Approximate signed distance of one primitive at broadcastable coordinates (float32)."""
    f32 = np.float32
    if prim.kind == "capsule":
        a, b, ra, rb = prim.params
        ba = (b - a).astype(f32)
        px, py, pz = x - f32(a[0]), y - f32(a[1]), z - f32(a[2])
        s = np.clip((px * ba[0] + py * ba[1] + pz * ba[2]) / f32(ba @ ba), 0, 1)
        dx, dy, dz = px - s * ba[0], py - s * ba[1], pz - s * ba[2]
        return np.sqrt(dx * dx + dy * dy + dz * dz) - (f32(ra) + s * f32(rb - ra))
    if prim.kind == "ellipsoid":
        c, axes, semi = prim.params
        px, py, pz = x - f32(c[0]), y - f32(c[1]), z - f32(c[2])
        k0sq = 0.0
        k1sq = 0.0
        for i in range(3):
            li = px * f32(axes[i, 0]) + py * f32(axes[i, 1]) + pz * f32(axes[i, 2])
            k0sq = k0sq + (li / f32(semi[i])) ** 2
            k1sq = k1sq + (li / f32(semi[i] ** 2)) ** 2
        k0, k1 = np.sqrt(k0sq), np.sqrt(k1sq)
        return np.where(k1 > 1e-9, k0 * (k0 - 1) / np.maximum(k1, 1e-9), -f32(semi.min()))
    (torso,) = prim.params
    a, b, zc = (v.astype(f32) for v in torso.sections(np.asarray(y, np.float64)))
    px, pz = x, z - zc
    k0 = np.sqrt((px / a) ** 2 + (pz / b) ** 2)
    k1 = np.sqrt((px / (a * a)) ** 2 + (pz / (b * b)) ** 2)
    d2 = np.where(k1 > 1e-9, k0 * (k0 - 1) / np.maximum(k1, 1e-9), -np.minimum(a, b))
    dy = np.maximum(f32(torso.y0) - y, y - f32(torso.y1))
    mid = 0.5 * (torso.y0 + torso.y1)
    rr = np.where(y < mid, f32(torso.round_bottom), f32(torso.round_top)).astype(f32)
    wx, wy = d2 + rr, dy + rr
    inside = np.minimum(np.maximum(wx, wy), 0)
    outside = np.sqrt(np.maximum(wx, 0) ** 2 + np.maximum(wy, 0) ** 2)
    return inside + outside - rr


def _smin(a, b, k: float):
    """Polynomial smooth minimum with blend radius ``k`` (exact min when ``|a - b| >= k``)."""
    if k <= 0:
        return np.minimum(a, b)
    hh = np.maximum(k - np.abs(a - b), 0) / k
    return np.minimum(a, b) - hh * hh * (k * 0.25)


def body_field(shape: BodyShape, points: np.ndarray) -> np.ndarray:
    """The mannequin's implicit function (negative inside) at ``points`` (N, 3): (N,) float32.

    Approximately the signed distance near the surface (exact for the capsules, close for
    the ellipses): a cheap inside/outside and clearance test, e.g. for fitting garments. The
    torso is girth-fitted; the vertices of ``make_body(shape)`` lie on its zero level.
    """
    pts = np.asarray(points, np.float32)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"points must be (N, 3), got {pts.shape}")
    prims = _fitted_primitives(shape, _min_radius(shape, DEFAULT_RESOLUTION))
    return _field_at(prims, pts[:, 0], pts[:, 1], pts[:, 2])


def _field_at(prims, x, y, z):
    base, chains = prims
    f0 = _eval_prim(base[0], x, y, z)
    for prim in base[1:]:
        f0 = _smin(f0, _eval_prim(prim, x, y, z), prim.blend)
    f = f0
    for chain in chains:
        c = f0
        for prim in chain:
            c = _smin(c, _eval_prim(prim, x, y, z), prim.blend)
        f = np.minimum(f, c)
    return f


def torso_range(shape: BodyShape) -> tuple[float, float]:
    """Bottom (crotch) and top (shoulders) heights of the torso, metres."""
    return TORSO_BOTTOM * shape.height, TORSO_TOP * shape.height


def _min_radius(shape: BodyShape, resolution: int) -> float:
    return 1.6 * _voxel_size(shape, resolution)


def _voxel_size(shape: BodyShape, resolution: int) -> float:
    """Grid spacing: a point budget over the body's rough bounding box."""
    h = shape.height
    width = max(shape.shoulder_width + 0.75 * h, 0.7 * max(shape.hip, shape.waist, shape.chest))
    depth = max(0.2 * h, 0.45 * max(shape.hip, shape.waist, shape.chest))
    budget = float(np.clip(resolution * 300, 1.5e6, 8e6))
    return (h * width * depth / budget) ** (1 / 3)


def _girths_of_field(prims, torso: _TorsoProfile, levels: dict[str, float]) -> dict[str, float]:
    """Tape-measure girths of the field's torso at ``levels``: convex hull of the first
    zero crossing along rays from the torso centre."""
    from scipy.spatial import ConvexHull

    angles = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    out = {}
    base, chains = prims

    def near(q: _Prim, y: float) -> bool:
        return q.kind == "torso" or q.lo[1] - q.blend <= y <= q.hi[1] + q.blend

    for name, y in levels.items():
        # Primitives away from the plane change nothing there (not even by blending).
        sliced = (
            [q for q in base if near(q, y)],
            [c for c in ([q for q in chain if near(q, y)] for chain in chains) if c],
        )
        a, b, zc = (float(v[0]) for v in torso.sections(np.array([y])))
        rmax = 1.5 * max(a, b) + 0.05
        radii = np.linspace(0, rmax, 200)
        x = (np.cos(angles)[:, None] * radii).astype(np.float32)
        z = (zc + np.sin(angles)[:, None] * radii).astype(np.float32)
        f = _field_at(sliced, x, np.full_like(x, y), z)
        outside = f > 0
        first = np.argmax(outside, axis=1)  # first sample outside along each ray
        first = np.maximum(first, 1)
        rows = np.arange(len(angles))
        f0, f1 = f[rows, first - 1], f[rows, first]
        t = np.clip(f0 / np.where(f0 != f1, f0 - f1, 1), 0, 1)
        rad = radii[first - 1] + t * (radii[first] - radii[first - 1])
        pts = np.stack([np.cos(angles) * rad, np.sin(angles) * rad], axis=1)
        out[name] = float(ConvexHull(pts).area)  # in 2-D, "area" is the perimeter
    return out


@functools.lru_cache(maxsize=32)
def _fitted_primitives(shape: BodyShape, min_r: float):
    """Primitives with the torso keys rescaled until the field's girths match ``shape``."""
    skeleton = mannequin_skeleton(shape)
    h = shape.height
    levels = {"hip": HIP_LEVEL * h, "waist": WAIST_LEVEL * h, "chest": CHEST_LEVEL * h}
    target = {"hip": shape.hip, "waist": shape.waist, "chest": shape.chest}
    scale = {k: 1.0 for k in target}
    for _ in range(4):
        torso = _torso_profile(shape, scale)
        prims = _primitives(shape, skeleton, torso, min_r)
        got = _girths_of_field(prims, torso, levels)
        err = {k: target[k] / got[k] for k in target}
        if all(abs(e - 1) < 0.002 for e in err.values()):
            break
        scale = {k: float(np.clip(scale[k] * err[k], 0.5, 1.5)) for k in target}
    return prims


def body_mesh(shape: BodyShape, resolution: int = DEFAULT_RESOLUTION):
    """The mannequin's rest surface, without skinning.

    Returns
    -------
    vertices : (V, 3) float32
    faces : (F, 3) int64
        Closed, manifold, outward-oriented; ``V`` close to ``resolution``.
    """
    import igl

    voxel = _voxel_size(shape, resolution)
    prims = _fitted_primitives(shape, 1.6 * voxel)
    base, chains = prims
    every = base + [q for chain in chains for q in chain]
    lo = np.min([q.lo for q in every], axis=0) - 3 * voxel
    hi = np.max([q.hi for q in every], axis=0) + 3 * voxel
    n = np.ceil((hi - lo) / voxel).astype(int) + 1
    axes = [(lo[i] + voxel * np.arange(n[i])).astype(np.float32) for i in range(3)]
    outside = np.float32(4 * voxel)
    pad = 3 * voxel

    def block(q: _Prim, margin: float = 0.0) -> tuple[slice, slice, slice]:
        return tuple(
            slice(
                int(np.searchsorted(axes[i], q.lo[i] - pad - q.blend - margin)),
                int(np.searchsorted(axes[i], q.hi[i] + pad + q.blend + margin, side="right")),
            )
            for i in range(3)
        )

    def values(q: _Prim, sl) -> np.ndarray:
        x = axes[0][sl[0], None, None]
        y = axes[1][None, sl[1], None]
        z = axes[2][None, None, sl[2]]
        return np.minimum(_eval_prim(q, x, y, z), outside)

    base_grid = np.full(tuple(n), outside, np.float32)
    for k, q in enumerate(base):
        sl = block(q)
        d = values(q, sl)
        base_grid[sl] = d if k == 0 else _smin(base_grid[sl], d, q.blend)
    grid = base_grid.copy()
    for chain in chains:
        c_lo = np.min([q.lo for q in chain], axis=0)
        c_hi = np.max([q.hi for q in chain], axis=0)
        k_max = max(q.blend for q in chain)
        box = _Prim("box", (), k_max, c_lo, c_hi)
        sl = block(box)
        c = base_grid[sl].copy()
        offset = [s_.start for s_ in sl]
        for q in chain:
            qs = block(q)
            qs = tuple(slice(max(a.start, b.start), min(a.stop, b.stop)) for a, b in zip(qs, sl))
            local = tuple(slice(a.start - o, a.stop - o) for a, o in zip(qs, offset))
            c[local] = _smin(c[local], values(q, qs), q.blend)
        grid[sl] = np.minimum(grid[sl], c)
    # libigl wants S(x + y*nx + z*nx*ny): x fastest, so Fortran order.
    s = grid.ravel(order="F").astype(np.float64)
    gx, gy, gz = np.meshgrid(*axes, indexing="ij")
    gv = np.stack([g.ravel(order="F") for g in (gx, gy, gz)], axis=1).astype(np.float64)
    v, f, _ = igl.marching_cubes(s, gv, int(n[0]), int(n[1]), int(n[2]), 0.0)
    v, f = _largest_component(v, f)
    v, f = _decimate(v, f, resolution)
    if _signed_volume(v, f) < 0:
        f = f[:, ::-1].copy()
    v, f = _remove_valence3(v, f)
    v = _relax(v, f, prims)
    return v.astype(np.float32), f.astype(np.int64)


def _remove_valence3(v: np.ndarray, f: np.ndarray, passes: int = 4):
    """Replace each vertex with only three neighbours (and its three slivers) by one triangle
    on its neighbours; keeps the mesh closed, manifold and oriented."""
    f = f.copy()
    for _ in range(passes):
        incident = np.bincount(f.ravel(), minlength=len(v))
        cand = np.nonzero(incident == 3)[0]
        if len(cand) == 0:
            break
        face_of = np.argsort(f.ravel(), kind="stable") // 3
        start = np.concatenate([[0], np.cumsum(incident)])
        taken = np.zeros(len(v), bool)
        drop, add = [], []
        existing = {tuple(sorted(t)) for t in f.tolist()}
        for x in cand:
            fs = face_of[start[x] : start[x] + 3]
            ring = set(f[fs].ravel().tolist()) - {int(x)}
            if taken[x] or taken[list(ring)].any() or len(ring) != 3:
                continue
            # Walk the fan: for a face (x, a, b) the replacing face keeps the order a -> b.
            nxt = {}
            for t in f[fs]:
                k = int(np.nonzero(t == x)[0][0])
                nxt[int(t[(k + 1) % 3])] = int(t[(k + 2) % 3])
            a = next(iter(nxt))
            tri = (a, nxt[a], nxt[nxt[a]])
            if tuple(sorted(tri)) in existing or nxt[tri[2]] != a:
                continue
            taken[x] = True
            taken[list(ring)] = True
            drop.extend(fs.tolist())
            add.append(tri)
            existing.add(tuple(sorted(tri)))
        if not add:
            break
        keep = np.ones(len(f), bool)
        keep[drop] = False
        f = np.concatenate([f[keep], np.asarray(add, f.dtype)])
    return _drop_unreferenced(v, f)


def _relax(v: np.ndarray, f: np.ndarray, prims, iterations: int = RELAX_ITERATIONS):
    """Even out the decimated triangles: move each vertex towards the mean of its neighbours
    within its tangent plane, then back onto the implicit surface along the normal (the
    field is close to a signed distance, so one step of ``-f n`` lands on it)."""
    import igl
    from scipy.sparse import coo_matrix, diags

    e = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(v),) * 2).tocsr()
    adj = ((adj + adj.T) > 0).astype(np.float64)
    avg = diags(1.0 / np.asarray(adj.sum(axis=1)).ravel()) @ adj
    v = v.astype(np.float64)
    # Reference orientation of each face: the field's gradient at its centre.
    ref = _field_gradient(prims, v[f].mean(axis=1))
    for _ in range(iterations):
        n = igl.per_vertex_normals(v, f)
        d = avg @ v - v
        d -= np.einsum("ij,ij->i", d, n)[:, None] * n
        moved = v + 0.5 * d
        dist = _field_at(prims, *(moved.astype(np.float32).T)).astype(np.float64)
        moved -= np.clip(dist, -0.01, 0.01)[:, None] * n
        # A vertex whose move would turn one of its triangles away from the surface's
        # orientation (or further away, if it already was) takes a shorter step.
        floor = np.minimum(np.einsum("ij,ij->i", ref, _face_normals(v, f)), 0.3)
        for attempt in range(8):
            turned = np.einsum("ij,ij->i", ref, _face_normals(moved, f)) < floor - 1e-9
            if not turned.any():
                break
            back = np.unique(f[turned])  # their vertices step back half-way (then all the way)
            moved[back] = v[back] if attempt == 7 else 0.5 * (v[back] + moved[back])
        v = moved
    return v


def _field_gradient(prims, points: np.ndarray, eps: float = 1e-4) -> np.ndarray:
    """Unit gradient of the field (the outward normal) at points (N, 3): (N, 3) float64."""
    p = points.astype(np.float32)
    g = np.stack(
        [
            _field_at(prims, *(p + eps * e).T) - _field_at(prims, *(p - eps * e).T)
            for e in np.eye(3, dtype=np.float32)
        ],
        axis=1,
    ).astype(np.float64)
    return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)


def _face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)


def _largest_component(v: np.ndarray, f: np.ndarray):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    # libigl's marching cubes shares vertices along grid edges; drop collapsed triangles.
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    e = f[:, [0, 1, 1, 2]].reshape(-1, 2)
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(v),) * 2)
    _, labels = connected_components(adj, directed=False)
    counts = np.bincount(labels[f[:, 0]])
    keep = f[labels[f[:, 0]] == np.argmax(counts)]
    used = np.unique(keep)
    remap = np.full(len(v), -1, np.int64)
    remap[used] = np.arange(len(used))
    return v[used], remap[keep]


def _decimate(v: np.ndarray, f: np.ndarray, resolution: int):
    """Quadric decimation to about ``1.05 * resolution`` vertices (closed: F = 2V - 4).

    Quadric collapses can, rarely, pinch an edge into a non-manifold one; such a result is
    refused and the decimation retried with other settings.
    """
    import fast_simplification

    # About 5% of the vertices quadric decimation leaves have valence 3 and are removed after.
    target_faces = 2 * round(resolution * 1.05) - 4
    if len(f) <= target_faces:
        return v, f
    euler = len(v) - len(f) // 2  # V - E + F of a closed mesh (E = 3F/2)
    attempts = [(5.0, target_faces), (3.0, target_faces + 2), (7.0, target_faces - 2)]
    attempts += [(4.0, target_faces + 40), (6.0, target_faces - 40), (2.0, target_faces + 100)]
    for agg, target in attempts:
        v2, f2 = fast_simplification.simplify(
            v.astype(np.float64), f.astype(np.int32), target_count=target, agg=agg
        )
        v2, f2 = _drop_unreferenced(v2, f2.astype(np.int64))
        if is_closed_manifold(f2) and len(v2) - len(f2) // 2 == euler:
            return v2, f2
    raise RuntimeError(f"decimation to {resolution} vertices kept breaking the mesh's topology")


def _drop_unreferenced(v: np.ndarray, f: np.ndarray):
    used = np.unique(f)
    remap = np.full(len(v), -1, np.int64)
    remap[used] = np.arange(len(used))
    return v[used], remap[f]


def is_closed_manifold(faces: np.ndarray) -> bool:
    """Every edge shared by exactly two faces, in opposite directions (consistent winding),
    and every vertex's faces form a single fan.

    Parameters
    ----------
    faces : (F, 3) int
    """
    f = np.asarray(faces, np.int64)
    nv = int(f.max()) + 1
    directed = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    # Each directed edge once, and its reverse present: closed, 2-manifold edges, consistent.
    d_keys = np.unique(directed[:, 0] * nv + directed[:, 1])
    if len(d_keys) != len(directed):
        return False
    rev = directed[:, 1] * nv + directed[:, 0]
    if len(np.unique(np.concatenate([d_keys, rev]))) != len(d_keys):
        return False
    # Vertex manifoldness: around each vertex, faces = edges of its link (one cycle per fan).
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    # Link edges (b, c) opposite each vertex a, as nodes (a, b) -> (a, c) in a graph of
    # (vertex, neighbour) pairs; one component per vertex means one fan.
    a = f.reshape(-1)
    b = np.roll(f, -1, axis=1).reshape(-1)
    c = np.roll(f, -2, axis=1).reshape(-1)
    pairs, inv = np.unique(np.concatenate([a * nv + b, a * nv + c]), return_inverse=True)
    m = len(a)
    adj = coo_matrix((np.ones(m), (inv[:m], inv[m:])), shape=(len(pairs),) * 2)
    _, labels = connected_components(adj, directed=False)
    owner = pairs // nv
    return len(np.unique(labels)) == len(np.unique(owner))


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


# --------------------------------------------------------------------------------------------
# Measuring
# --------------------------------------------------------------------------------------------


def girth_at(vertices: np.ndarray, faces: np.ndarray, y: float, center_xz=(0.0, 0.0)) -> float:
    """Tape-measure girth of a closed mesh at height ``y``.

    Slices the mesh with the plane Y = ``y``, keeps the cross-section loop that encloses
    ``center_xz`` (the torso, not the arms) and returns the perimeter of its convex hull.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    y : float
        Height of the horizontal plane, metres.
    center_xz : (2,) float
        A point inside the wanted loop (x, z).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import ConvexHull

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    s = v[:, 1] - y
    s = np.where(s == 0, 1e-12, s)  # no vertex exactly on the plane
    edges = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 3, 2), axis=2)
    crosses = (s[edges[..., 0]] > 0) != (s[edges[..., 1]] > 0)  # (F, 3)
    hit = crosses.sum(1) == 2
    if not hit.any():
        raise InputError(f"the mesh does not reach height {y:.3f} m")
    e = edges[hit][crosses[hit]].reshape(-1, 2, 2)  # two crossing edges per face
    # Points on crossing edges, keyed by the (sorted) edge so that faces share them.
    keys, inv = np.unique(e.reshape(-1, 2), axis=0, return_inverse=True)
    inv = inv.reshape(-1, 2)
    t = s[keys[:, 0]] / (s[keys[:, 0]] - s[keys[:, 1]])
    pts = v[keys[:, 0]] + t[:, None] * (v[keys[:, 1]] - v[keys[:, 0]])
    adj = coo_matrix((np.ones(len(inv)), (inv[:, 0], inv[:, 1])), shape=(len(pts),) * 2)
    _, labels = connected_components(adj, directed=False)
    cx, cz = float(center_xz[0]), float(center_xz[1])
    best = None
    for lab in np.unique(labels):
        seg = inv[labels[inv[:, 0]] == lab]
        p, q = pts[seg[:, 0]][:, [0, 2]], pts[seg[:, 1]][:, [0, 2]]
        # Ray from the centre along +x: count segment crossings (even-odd rule).
        straddle = (p[:, 1] > cz) != (q[:, 1] > cz)
        xs = p[:, 0] + (cz - p[:, 1]) * (q[:, 0] - p[:, 0]) / np.where(
            q[:, 1] != p[:, 1], q[:, 1] - p[:, 1], 1
        )
        if (straddle & (xs > cx)).sum() % 2 == 1:
            loop = pts[labels == lab][:, [0, 2]]
            perim = float(ConvexHull(loop).area)
            if best is None or perim < best:
                best = perim
    if best is None:
        raise InputError(f"no cross-section at height {y:.3f} m encloses {center_xz}")
    return best
