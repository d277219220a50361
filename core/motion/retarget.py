"""Retargeting: world joint positions of any rig -> a clip on the mannequin skeleton.

The source is a (T, 20, 3) array of world joint positions (Hips, then the 19 canonical joints),
in metres, Y up, as the BVH loader and its joint mapping produce. The result drives the
mannequin (:func:`core.body.shape.mannequin_skeleton`) so that every mannequin bone points where
the source bone points; bone lengths stay the mannequin's because only rotations are solved.

How each joint's world orientation is found (rest pose = identity, so a frame is fixed by where
it sends a few rest directions):

- Hips and Spine2 (three children each) are fitted, Kabsch style, to two directions: the hip
  line (left hip - right hip) and the spine-up direction for the pelvis; the neck direction
  and the shoulder line for the chest.
- Single-child joints take the minimal rotation (swing) from the parent's frame that makes the
  bone point where the source bone points, then a twist about the bone: the spine joints share
  the twist between pelvis and chest; upper arms and thighs take the twist of the limb's bend
  plane (elbow, knee), but only as far as the limb is bent: a straight or slightly
  hyperextended limb keeps the parent's twist, so nothing flips when a limb straightens.
  That roll is low-passed over time (:data:`TWIST_SMOOTHING_S`); it moves no joint.
- Forearms and shins swing from the upper limb (a hinge); hands and the head follow their parent.
- Feet are flat (sole level, heading of the shin) when the source ankle is near its floor and
  follow the shin when it is lifted.

The root moves like the source hips, scaled by the ratio of leg lengths; its height is set so the
lower ankle is as far above the floor as the source's (scaled); no foot point ever goes below
y = 0. The source's floor is estimated robustly (:func:`estimate_floor`: the lowest height of
the lower ankle that several frames reach), so that one frame where a foot dips
(a marker swap, a badly calibrated floor) does not lift the whole clip; such frames are reported
and stand on the floor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.body.shape import MANNEQUIN_JOINTS, BodyShape, mannequin_skeleton
from core.errors import InputError
from core.motion.motion import Motion
from core.numeric import smoothstep
from core.skeleton import CANONICAL_JOINTS, ROOT_JOINT, Skeleton, forward_kinematics

#: Order of the joints in a source position array: the root, then the canonical 19.
SOURCE_JOINTS: tuple[str, ...] = (ROOT_JOINT,) + CANONICAL_JOINTS
_SRC = {n: i for i, n in enumerate(SOURCE_JOINTS)}
_X, _Y, _Z = np.eye(3)
#: Standard deviation (seconds) of the low-pass on upper-arm and thigh roll (twist).
TWIST_SMOOTHING_S = 0.04
#: The default body (``BodyShape()``): frozen, so one shared instance is safe as a default.
DEFAULT_SHAPE = BodyShape()


# --------------------------------------------------------------------------------------------
# Small rotation helpers on stacks of vectors / matrices (float64).


def _norm(v: np.ndarray) -> np.ndarray:
    return np.linalg.norm(v, axis=-1)


def _unit(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """``v / |v|`` on (..., 3); where ``|v|`` is tiny, the (broadcast) ``fallback`` instead."""
    v = np.asarray(v, np.float64)
    n = _norm(v)[..., None]
    fb = np.broadcast_to(np.asarray(fallback, np.float64), v.shape)
    return np.where(n > 1e-9, v / np.maximum(n, 1e-300), fb)


def rotation_about_axes(axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rodrigues: rotations about ``axes`` (..., 3) (normalised here) by ``angles`` (...,).

    Returns (..., 3, 3) float64. A zero axis gives the identity.
    """
    a = np.asarray(axes, np.float64)
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    a = np.where(n > 1e-12, a / np.maximum(n, 1e-300), 0.0)
    t = np.asarray(angles, np.float64)
    a, t = np.broadcast_arrays(a, t[..., None])
    t = t[..., 0]
    x, y, z = a[..., 0], a[..., 1], a[..., 2]
    zero = np.zeros_like(x)
    k = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(a.shape[:-1] + (3, 3))
    s, c = np.sin(t)[..., None, None], np.cos(t)[..., None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def swing_rotation(a: np.ndarray, b: np.ndarray, fallback_axis: np.ndarray) -> np.ndarray:
    """Minimal rotations taking unit vectors ``a`` to ``b`` (both (..., 3)): (..., 3, 3).

    Where ``a`` and ``b`` are opposite the axis is undefined; the rotation is then half a turn
    about ``fallback_axis`` (..., 3) made perpendicular to ``a``.
    """
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    v = np.cross(a, b)
    c = np.sum(a * b, -1)
    zero = np.zeros_like(c)
    k = np.stack(
        [zero, -v[..., 2], v[..., 1], v[..., 2], zero, -v[..., 0], -v[..., 1], v[..., 0], zero],
        -1,
    ).reshape(v.shape[:-1] + (3, 3))
    safe = c > -1.0 + 1e-9
    denom = np.where(safe, 1.0 + c, 1.0)[..., None, None]
    r = np.eye(3) + k + (k @ k) / denom
    if not safe.all():
        fb = np.broadcast_to(np.asarray(fallback_axis, np.float64), a.shape)
        fb = fb - np.sum(fb * a, -1, keepdims=True) * a
        other = np.where(np.abs(a[..., :1]) < 0.9, _X, _Y)
        fb = _unit(fb, _unit(np.cross(a, other), _Z))
        r = np.where(safe[..., None, None], r, rotation_about_axes(fb, np.pi))
    return r


def kabsch(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Rotations R minimising ``sum_i w_i |R src_i - dst_i|^2``.

    src : (..., N, 3) float, dst : (..., N, 3) float, weights : (N,) or (..., N) float.
    Returns (..., 3, 3) float64, proper rotations (det +1).
    """
    w = np.asarray(weights, np.float64)
    m = np.einsum("...n,...ni,...nj->...ij", np.broadcast_to(w, dst.shape[:-1]), dst, src)
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0, 1.0, d)
    u = u.copy()
    u[..., :, 2] *= d[..., None]
    return u @ vt


def _slerp_rotations(r0: np.ndarray, r1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Geodesic blend of rotations (T, 3, 3) with weights (T,): w=0 gives r0, w=1 gives r1."""
    from scipy.spatial.transform import Rotation

    rel = np.einsum("tji,tjk->tik", r0, r1)
    rv = Rotation.from_matrix(rel).as_rotvec()
    return r0 @ Rotation.from_rotvec(rv * np.asarray(w)[:, None]).as_matrix()


def _blend_dir(primary: np.ndarray, conf: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Unit ``conf * unit(primary) + (1 - conf) * fallback`` on (T, 3); fallback is unit."""
    v = conf[:, None] * _unit(primary, fallback) + (1.0 - conf[:, None]) * fallback
    return _unit(v, fallback)


# --------------------------------------------------------------------------------------------
# Per-joint solvers.


def _swing_from_parent(
    g_parent: np.ndarray, d_rest: np.ndarray, d: np.ndarray, hinge_rest: np.ndarray | None = None
) -> np.ndarray:
    """Parent frame (T,3,3) rotated minimally so rest direction ``d_rest`` (3,) lands on ``d``."""
    a = g_parent @ d_rest
    fb = g_parent @ (hinge_rest if hinge_rest is not None else np.cross(d_rest, _Z + 0.3 * _X))
    return swing_rotation(a, d, fb) @ g_parent


def twist_towards(
    g_swing: np.ndarray,
    d: np.ndarray,
    ref_rest: np.ndarray,
    target: np.ndarray,
    limb: bool,
    smooth_frames: float = 0.0,
) -> np.ndarray:
    """Turn ``g_swing`` (T,3,3) about ``d`` (T,3) so ``g @ ref_rest`` heads towards ``target``.

    ``ref_rest`` (3,) is perpendicular to the bone's rest direction. For a limb, ``target`` is the
    child bone's direction and the twist is applied only as far as the limb is bent the natural
    way (a straight or slightly hyperextended limb keeps the swing's twist); otherwise the twist
    is applied in full wherever ``target`` has a clear component across the bone.
    ``smooth_frames`` > 0 low-passes the twist angle over the frames (a Gaussian of that
    standard deviation), which calms fast roll changes where a limb straightens or bends; the
    bone direction, and so every joint position, is unaffected.
    """
    r = g_swing @ ref_rest
    t = target - np.sum(target * d, -1, keepdims=True) * d
    p = np.sum(t * r, -1)
    q = np.sum(t * np.cross(d, r), -1)
    phi = np.arctan2(q, p)
    if limb:
        fwd = np.hypot(np.maximum(p, 0.0), q)
        conf = np.maximum(
            smoothstep(fwd, np.sin(np.radians(10)), np.sin(np.radians(30))),
            smoothstep(-p, np.sin(np.radians(45)), np.sin(np.radians(60))),
        )
    else:
        conf = smoothstep(np.hypot(p, q), 0.05, 0.2)
    angle = conf * phi
    if smooth_frames > 0.5 and len(angle) > 1:
        from scipy.ndimage import gaussian_filter1d

        angle = gaussian_filter1d(np.unwrap(angle), smooth_frames, mode="nearest")
    return rotation_about_axes(d, angle) @ g_swing


def _perp(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v - np.dot(v, axis) * axis


class _Chains:
    """Direction vectors with fallbacks, computed the same way on the source and the rest pose."""

    def __init__(self, pos: np.ndarray, leg: float):
        self.pos = pos  # (T, 20, 3) float64, source order
        self.leg = leg

    def p(self, name: str) -> np.ndarray:
        return self.pos[:, _SRC[name]]

    def vec(self, a: str, b: str) -> np.ndarray:
        return self.p(b) - self.p(a)

    def conf(self, v: np.ndarray, lo: float, hi: float) -> np.ndarray:
        return smoothstep(_norm(v) / self.leg, lo, hi)

    def chain(self, vectors: list[np.ndarray], lo: float, hi: float, last: np.ndarray):
        """First vector of the list that is long enough, blended smoothly into the next."""
        out = np.broadcast_to(last, vectors[0].shape).astype(np.float64)
        for v in reversed(vectors):
            out = _blend_dir(v, self.conf(v, lo, hi), out)
        return out

    def hip_line(self) -> np.ndarray:
        return self.chain(
            [self.vec("RightUpLeg", "LeftUpLeg"), self.vec("RightArm", "LeftArm")], 0.02, 0.08, _X
        )

    def pelvis_up(self) -> np.ndarray:
        vs = [self.vec("Hips", n) for n in ("Spine", "Spine1", "Spine2", "Neck")]
        return self.chain(vs, 0.03, 0.08, _Y)

    def shoulder_line(self) -> np.ndarray:
        vs = [self.vec("RightShoulder", "LeftShoulder"), self.vec("RightArm", "LeftArm")]
        return self.chain(vs + [self.vec("RightUpLeg", "LeftUpLeg")], 0.02, 0.05, _X)

    def chest_up(self) -> np.ndarray:
        vs = [self.vec("Spine2", "Neck"), self.vec("Spine2", "Head"), self.vec("Spine1", "Neck")]
        return self.chain(vs + [self.vec("Hips", "Neck")], 0.02, 0.05, _Y)


def _bone_dir(ch: _Chains, a: str, b: str, g_parent: np.ndarray, d_rest: np.ndarray):
    """Source direction of bone a->b, falling back on the parent's frame where it is too short."""
    return _blend_dir(ch.vec(a, b), ch.conf(ch.vec(a, b), 0.005, 0.02), g_parent @ d_rest)


# --------------------------------------------------------------------------------------------


def foot_points(skeleton: Skeleton, positions: np.ndarray, global_rotations: np.ndarray):
    """World positions of the contact points of both feet: ankle, heel and toe.

    Parameters
    ----------
    skeleton : the mannequin skeleton (joints ``LeftFoot``/``RightFoot`` with toe end sites)
    positions : (T, J, 3) float, global_rotations : (T, J, 3, 3) float
        Outputs of :func:`core.skeleton.forward_kinematics`.

    Returns
    -------
    (T, 2, 3, 3) float64
        ``[t, foot, point]`` with foot 0 = left, 1 = right and point 0 = ankle, 1 = heel, 2 = toe.
    """
    out = []
    for side in ("Left", "Right"):
        j = skeleton.index(f"{side}Foot")
        toe = skeleton.end_sites[j].astype(np.float64)
        heel = np.array([0.0, toe[1], -0.25 * toe[2]])
        local = np.stack([np.zeros(3), heel, toe])
        p = np.asarray(positions, np.float64)[:, j]
        r = np.asarray(global_rotations, np.float64)[:, j]
        out.append(p[:, None] + np.einsum("tab,kb->tka", r, local))
    return np.stack(out, 1)


def _local_rotations(skel: Skeleton, g: dict[str, np.ndarray]) -> np.ndarray:
    """Local rotations (T, J, 3, 3) float64 from world orientations by joint name."""
    glob = np.stack([g[n] for n in skel.names], 1)
    local = glob.copy()
    for j, p in enumerate(skel.parents):
        if p >= 0:
            local[:, j] = np.einsum("tji,tjk->tik", glob[:, p], glob[:, j])
    return local


def _foot_above_floor(
    relaxed: np.ndarray, flat: np.ndarray, w: np.ndarray, sole: np.ndarray, ankle_y: np.ndarray
) -> np.ndarray:
    """Blend ``relaxed`` towards ``flat`` (T,3,3) by at least ``w`` (T,), and further where the
    sole points ``sole`` (K, 3) (ankle-relative, rest frame) would dip below y = 0 with the
    ankle at height ``ankle_y`` (T,). Flat always clears the floor when the ankle is at or above
    its rest height, so a blend weight exists; it is found by bisection."""
    from scipy.spatial.transform import Rotation

    rv = Rotation.from_matrix(np.einsum("tji,tjk->tik", relaxed, flat)).as_rotvec()

    def lowest(weight: np.ndarray) -> np.ndarray:
        r = relaxed @ Rotation.from_rotvec(rv * weight[:, None]).as_matrix()
        return ankle_y + np.einsum("tab,kb->tka", r, sole)[..., 1].min(1)

    lo, hi = np.asarray(w, np.float64), np.ones_like(ankle_y)
    ok = lowest(lo) >= 0.0
    lo_bad = lo
    for _ in range(14):
        mid = 0.5 * (lo_bad + hi)
        good = lowest(mid) >= 0.0
        hi = np.where(good, mid, hi)
        lo_bad = np.where(good, lo_bad, mid)
    weight = np.where(ok, w, hi)
    return relaxed @ Rotation.from_rotvec(rv * weight[:, None]).as_matrix()


def _validate(positions: np.ndarray, fps: float) -> np.ndarray:
    pos = np.asarray(positions)
    if pos.ndim != 3 or pos.shape[1:] != (len(SOURCE_JOINTS), 3) or len(pos) < 1:
        raise InputError(
            f"retarget needs positions of shape (T, {len(SOURCE_JOINTS)}, 3) "
            f"(Hips then the 19 canonical joints), got {pos.shape}"
        )
    if not np.issubdtype(pos.dtype, np.number):
        raise InputError(f"retarget needs numeric positions, got dtype {pos.dtype}")
    pos = pos.astype(np.float64)
    if not np.isfinite(pos).all():
        bad = np.argwhere(~np.isfinite(pos).all(-1))[0]
        raise InputError(
            f"retarget: non-finite position at frame {bad[0]}, joint {SOURCE_JOINTS[bad[1]]}"
        )
    if not (isinstance(fps, (int, float, np.number)) and np.isfinite(fps) and fps > 0):
        raise InputError(f"retarget: fps must be a positive number, got {fps!r}")
    return pos


def _leg_length(pos: np.ndarray) -> float:
    """Median (thigh + shin) length over frames and both sides, in the array's units."""
    lengths = []
    for side in ("Left", "Right"):
        up, knee, ankle = (pos[:, _SRC[f"{side}{n}"]] for n in ("UpLeg", "Leg", "Foot"))
        lengths.append(_norm(knee - up) + _norm(ankle - knee))
    return float(np.median(np.concatenate(lengths)))


#: Floor estimate: the lowest height of the lower ankle that at least SUPPORT_SHARE of the
#: frames (and 2) reach within SUPPORT_BAND leg lengths above it. A dip of a frame or two (a
#: marker swap) has no such support and cannot set the floor; a clip's real lowest stance does.
#: A frame more than SUPPORT_BAND under the floor is reported as below it.
SUPPORT_SHARE = 0.02
SUPPORT_BAND = 0.012
#: Contacts (reported): the lower ankle within CONTACT_BAND leg lengths of the floor, moving
#: slower than CONTACT_SPEED leg lengths a second (a planted foot).
CONTACT_BAND = 0.05
CONTACT_SPEED = 0.5


@dataclass(frozen=True)
class FloorEstimate:
    """The source's floor and how it was found (heights in the source's metres, Y up).

    ``contacts`` (K,) int: frames where the lower ankle is planted near the floor; ``below``
    (J,) int: frames whose lower ankle is more than the tolerance under the floor;
    ``deepest_m``: how far the lowest of them is under it (0 when none); ``method``:
    ``support`` (estimated), ``given`` (a height from the user) or ``none`` (y = 0)."""

    height_m: float
    contacts: np.ndarray
    below: np.ndarray
    deepest_m: float
    method: str

    def summary(self, scale: float = 1.0) -> dict:
        """JSON-ready: the floor, the contacts as frame ranges, the frames below (``scale``
        turns the depth into the mannequin's metres)."""
        return {
            "method": self.method,
            "height_m": float(self.height_m),
            "contact_frames": int(len(self.contacts)),
            "contact_ranges": frame_ranges(self.contacts),
            "below_frames": [int(f) for f in self.below],
            "below_deepest_m": float(scale * self.deepest_m),
        }


def frame_ranges(frames: np.ndarray) -> list[list[int]]:
    """Sorted frame indices as ``[[first, last], ...]`` runs of consecutive frames."""
    frames = np.asarray(frames, np.int64)
    if len(frames) == 0:
        return []
    breaks = np.flatnonzero(np.diff(frames) != 1)
    starts = np.r_[frames[0], frames[breaks + 1]]
    ends = np.r_[frames[breaks], frames[-1]]
    return [[int(a), int(b)] for a, b in zip(starts, ends)]


def estimate_floor(
    ankles: np.ndarray, fps: float, leg: float, floor: str | float = "auto"
) -> FloorEstimate:
    """The floor under a clip from its two ankles.

    Parameters
    ----------
    ankles : (T, 2, 3) float
        Left and right ankle positions, metres, Y up.
    fps : float
        Frames per second (for the contacts' speed).
    leg : float
        The source's leg length, metres (the scale of the thresholds).
    floor : ``"auto"`` (estimated), ``"none"`` (y = 0, the source's own zero) or a height in
        the source's metres.
    """
    a = np.asarray(ankles, np.float64)
    t = len(a)
    side = a[..., 1].argmin(1)
    lower = a[np.arange(t), side]  # (T, 3) the lower ankle each frame
    low = lower[:, 1]
    if floor == "auto":
        order = np.sort(low)
        need = min(t, max(2, int(np.ceil(SUPPORT_SHARE * t))))
        reach = np.searchsorted(order, order + SUPPORT_BAND * leg, side="right") - np.arange(t)
        height, method = float(order[np.flatnonzero(reach >= need)[0]]), "support"
    elif floor == "none":
        height, method = 0.0, "none"
    else:
        height, method = float(floor), "given"
        if not np.isfinite(height):
            raise InputError(f"retarget: the floor height must be finite, got {floor!r}")
    velocity = np.gradient(lower, axis=0) * fps if t > 1 else np.zeros_like(lower)
    slow = np.linalg.norm(velocity, axis=1) <= CONTACT_SPEED * leg
    contacts = np.flatnonzero(slow & (np.abs(low - height) <= CONTACT_BAND * leg))
    below = np.flatnonzero(low < height - SUPPORT_BAND * leg)
    deepest = float(height - low.min()) if len(below) else 0.0
    return FloorEstimate(height, contacts, below, deepest, method)


def source_floor(positions: np.ndarray, fps: float, floor: str | float = "auto") -> FloorEstimate:
    """:func:`estimate_floor` of a source clip: ``positions`` (T, 20, 3) as :func:`retarget`
    takes them."""
    src = _validate(positions, fps)
    ankles = np.stack([src[:, SOURCE_JOINTS.index(f"{s}Foot")] for s in ("Left", "Right")], 1)
    return estimate_floor(ankles, fps, _leg_length(src), floor)


def retarget(
    positions: np.ndarray,
    fps: float,
    shape: BodyShape = DEFAULT_SHAPE,
    name: str = "",
    floor: str | float = "auto",
) -> Motion:
    """Drive the mannequin of ``shape`` with the joint positions of another rig.

    Parameters
    ----------
    positions : (T, 20, 3) float
        World joint positions in metres, Y up: ``Hips`` then :data:`CANONICAL_JOINTS`
        (the order of :data:`SOURCE_JOINTS`).
    fps : float
        Frames per second of the clip.
    shape : BodyShape
        The mannequin to drive.
    name : str
        Name of the clip, for reports.
    floor : ``"auto"``, ``"none"`` or a height in the source's metres (:func:`estimate_floor`)

    Returns
    -------
    Motion
        On ``mannequin_skeleton(shape)`` (joint order ``MANNEQUIN_JOINTS``), rotations
        (T, 20, 3, 3) float32 and root positions (T, 3) float32. ``meta`` holds ``scale``
        (mannequin leg length / source leg length), ``source_floor`` (the source's floor,
        metres) and ``floor`` (:meth:`FloorEstimate.summary`, depths in mannequin metres).

    Raises
    ------
    InputError
        Wrong shape, non-finite values, fps <= 0, or source legs of zero length.
    """
    src = _validate(positions, fps)
    skel = mannequin_skeleton(shape)
    rest_m = skel.rest_positions().astype(np.float64)
    rest = rest_m[[MANNEQUIN_JOINTS.index(n) for n in SOURCE_JOINTS]][None]
    leg_src, leg_m = _leg_length(src), _leg_length(rest)
    if not leg_src > 1e-6 * max(1.0, float(np.abs(src).max())):
        raise InputError("retarget: the source legs have zero length; cannot scale the clip")
    scale = leg_m / leg_src
    t = len(src)
    S, R = _Chains(src, leg_src), _Chains(rest, leg_m)

    def rest_dir(a: str, b: str) -> np.ndarray:
        return _unit(R.vec(a, b)[0], _Y)

    g: dict[str, np.ndarray] = {}
    # Pelvis and chest: best fit of two directions each.
    g["Hips"] = kabsch(
        np.stack([R.hip_line(), R.pelvis_up()], 1).repeat(t, 0),
        np.stack([S.hip_line(), S.pelvis_up()], 1),
        np.ones(2),
    )
    g["Spine2"] = kabsch(
        np.stack([R.shoulder_line(), R.chest_up()], 1).repeat(t, 0),
        np.stack([S.shoulder_line(), S.chest_up()], 1),
        np.ones(2),
    )
    # Spine: swing along the bones, twist shared between pelvis and chest.
    for joint, child, parent, share in (("Spine", "Spine1", "Hips", 1 / 3), ("Spine1", "Spine2", "Spine", 2 / 3)):  # fmt: skip
        d_rest = rest_dir(joint, child)
        d = _bone_dir(S, joint, child, g[parent], d_rest)
        sw = _swing_from_parent(g[parent], d_rest, d)
        across = (1 - share) * (g["Hips"] @ _X) + share * (g["Spine2"] @ _X)
        ref = _unit(_perp(_X, d_rest), _Z)
        g[joint] = twist_towards(sw, d, ref, across, limb=False)
    d_rest = rest_dir("Neck", "Head")
    g["Neck"] = _swing_from_parent(
        g["Spine2"], d_rest, _bone_dir(S, "Neck", "Head", g["Spine2"], d_rest)
    )
    g["Head"] = g["Neck"]
    # Limbs.
    limbs = (
        ("Shoulder", "Arm", "ForeArm", "Hand", "Spine2", _Z),
        ("UpLeg", "Leg", "Foot", None, "Hips", -_Z),
    )
    for side in ("Left", "Right"):
        for first, upper, lower, end, root, bend in limbs:
            if end is not None:  # clavicle: swing from the chest
                a, b = f"{side}{first}", f"{side}{upper}"
                d_rest = rest_dir(a, b)
                g[a] = _swing_from_parent(g[root], d_rest, _bone_dir(S, a, b, g[root], d_rest))
                parent, chain = a, (f"{side}{upper}", f"{side}{lower}", f"{side}{end}")
            else:
                parent, chain = root, (f"{side}{first}", f"{side}{upper}", f"{side}{lower}")
            j0, j1, j2 = chain
            d_rest = rest_dir(j0, j1)
            bend_rest = _unit(_perp(bend, d_rest), _Z)
            d = _bone_dir(S, j0, j1, g[parent], d_rest)
            sw = _swing_from_parent(g[parent], d_rest, d, np.cross(d_rest, bend_rest))
            child = _unit(S.vec(j1, j2), d)
            g[j0] = twist_towards(sw, d, bend_rest, child, True, TWIST_SMOOTHING_S * fps)
            d2_rest = rest_dir(j1, j2)
            hinge = np.cross(d_rest, bend_rest)
            d2 = _bone_dir(S, j1, j2, g[j0], d2_rest)
            g[j1] = _swing_from_parent(g[j0], d2_rest, d2, hinge)
            g[j2] = g[j1]  # hands and feet follow; feet are set below
    # Root height: the lower source ankle's height above the source floor, scaled; a frame
    # below the floor stands on it. Ankle positions do not depend on the feet's rotations, so
    # they are known before the feet.
    ankles_src = np.stack([S.p("LeftFoot")[:, 1], S.p("RightFoot")[:, 1]], 1)
    found = estimate_floor(np.stack([S.p("LeftFoot"), S.p("RightFoot")], 1), fps, leg_src, floor)
    floor_src = found.height_m
    ankle_rest = float(rest_m[MANNEQUIN_JOINTS.index("LeftFoot"), 1])
    elevation = scale * np.maximum(ankles_src - floor_src, 0.0)  # (T, 2), mannequin metres
    root = np.zeros((t, 3))
    root[:, [0, 2]] = scale * src[:, 0, [0, 2]]
    local = _local_rotations(skel, g)
    rel_pos = forward_kinematics(skel, local, np.zeros((t, 3)))[0].astype(np.float64)
    ankle_idx = [MANNEQUIN_JOINTS.index(f"{s}Foot") for s in ("Left", "Right")]
    rel_ankle = rel_pos[:, ankle_idx, 1]
    root[:, 1] = ankle_rest + elevation.min(1) - rel_ankle.min(1)
    for k, side in enumerate(("Left", "Right")):
        leg, hips = g[f"{side}Leg"], g["Hips"]
        heading = leg @ _Z
        heading[:, 1] = 0.0
        hips_heading = hips @ _Z
        hips_heading[:, 1] = 0.0
        fwd = _unit(heading + 0.05 * _unit(hips_heading, _Z), _Z)
        flat = np.stack([np.cross(_Y, fwd), np.broadcast_to(_Y, fwd.shape), fwd], -1)
        w = 1.0 - smoothstep(elevation[:, k], 0.01 * shape.height, 0.05 * shape.height)
        nj = len(skel.names)
        sole = foot_points(skel, np.zeros((1, nj, 3)), np.tile(np.eye(3), (1, nj, 1, 1)))
        sole = sole[0, k, 1:]  # heel and toe relative to the ankle, (2, 3)
        ankle_y = root[:, 1] + rel_ankle[:, k]
        g[f"{side}Foot"] = _foot_above_floor(leg, flat, w, sole, ankle_y)
    local = _local_rotations(skel, g)
    pos, rot = forward_kinematics(skel, local, root)
    lowest = foot_points(skel, pos, rot)[..., 1].min((1, 2))
    root[:, 1] += np.maximum(0.0, -lowest)  # only rounding is left to catch here
    return Motion(
        skeleton=skel,
        rotations=local.astype(np.float32),
        root_positions=root.astype(np.float32),
        fps=float(fps),
        name=name,
        meta={
            "source": "retarget",
            "scale": scale,
            "source_floor": floor_src,
            "floor": found.summary(scale),
        },
    )
