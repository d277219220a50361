"""The body as the cloth solver sees it: rigid capsules carried by the mannequin's bones.

One collider for the whole project: the simulation collides with it, Joint2Coarse pushes its
predictions out of it and is measured against it, and :class:`core.body.mannequin.Body`
carries it (``Body.capsules``).

Why capsules and not the skinned body mesh: a capsule is an exact, smooth signed-distance
shape, cheap to test a particle against (one segment distance), and it moves rigidly with one
bone, so the solver gets exact poses and velocities every substep. A skinned mesh collider
would need its BVH refitted every substep and gives faceted normals; on CPU that costs more
than the whole cloth solve of a 2k proxy.

The torso is a stack of horizontal capsules (stadium cross-sections) whose widths and depths
follow the mannequin's torso key sections (:func:`core.body.shape.torso_keys`, the same
ellipses the mannequin mesh is built from, before its girth fit); limbs are capsules along
their bones; the head a sphere. Posing a capsule is the rigid transform linear blend skinning
gives a vertex weighted fully to the capsule's joint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.body.shape import CHEST_LEVEL, BodyShape, mannequin_skeleton, torso_keys
from core.body.skinning import motion_arrays
from core.errors import InputError
from core.skeleton import Skeleton, forward_kinematics, skinning_transforms

#: Torso capsules are laid every this fraction of the height (dips between them ~3 mm).
_TORSO_STEP = 0.02


@dataclass(frozen=True)
class BodyCapsules:
    """Collision capsules of a body in its rest pose.

    Attributes
    ----------
    names : tuple of K str
        What each capsule is (``"torso-0.50"``, ``"LeftUpLeg"``...), for reports.
    joints : (K,) int64
        Index of the skeleton joint whose frame carries each capsule rigidly.
    endpoints : (K, 2, 3) float32
        Rest-pose (world) end points of each capsule's segment, metres.
    radii : (K,) float32
        Capsule radii, metres.
    """

    names: tuple[str, ...]
    joints: np.ndarray
    endpoints: np.ndarray
    radii: np.ndarray

    @property
    def count(self) -> int:
        return len(self.names)


def body_capsules(skeleton: Skeleton, shape: BodyShape) -> BodyCapsules:
    """Capsules for the mannequin ``skeleton`` built from ``shape`` (A-pose rest)."""
    h, t = shape.height, shape.thickness
    p = skeleton.rest_positions().astype(np.float64)
    ix = skeleton.index
    ys, key_a, key_b, key_z = torso_keys(shape)

    names: list[str] = []
    joints: list[int] = []
    ends: list[np.ndarray] = []
    radii: list[float] = []

    def add(name: str, joint: str, a: np.ndarray, b: np.ndarray, r: float) -> None:
        names.append(name)
        joints.append(ix(joint))
        ends.append(np.stack([a, b]))
        radii.append(r)

    for frac in np.arange(0.455, 0.80, _TORSO_STEP):
        y = frac * h
        a, b, z = (float(np.interp(y, ys, k)) for k in (key_a, key_b, key_z))
        c = max(a - b, 0.0)
        # A point between joints p and its child moves with p's frame (the bone p -> child).
        joint = "Hips"
        for name in ("Spine", "Spine1", "Spine2"):
            if y >= p[ix(name), 1]:
                joint = name
        add(f"torso-{frac:.3f}", joint, np.array([-c, y, z]), np.array([c, y, z]), b)

    def r(x: float) -> float:
        return x * h * t

    add("Neck", "Neck", p[ix("Neck")], p[ix("Head")], r(0.030))
    head_c = p[ix("Head")] + 0.5 * skeleton.end_sites[ix("Head")] + np.array([0, 0, 0.012 * h])
    add("Head", "Head", head_c, head_c, 0.052 * h)
    for side in ("Left", "Right"):
        arm, fore, hand = (p[ix(f"{side}{j}")] for j in ("Arm", "ForeArm", "Hand"))
        add(f"{side}Arm", f"{side}Arm", arm, fore, r(0.024))
        add(f"{side}ForeArm", f"{side}ForeArm", fore, hand, r(0.017))
        up, knee, foot = (p[ix(f"{side}{j}")] for j in ("UpLeg", "Leg", "Foot"))
        thigh = min(r(0.050), 0.9 * abs(up[0]))
        knee_r = min(r(0.030), thigh)
        mid = up + 0.45 * (knee - up)
        add(f"{side}UpLeg", f"{side}UpLeg", up, mid, thigh)
        add(f"{side}UpLeg-low", f"{side}UpLeg", mid, knee, 0.5 * (thigh + knee_r))
        add(f"{side}Leg", f"{side}Leg", knee, foot, min(r(0.032), thigh))
    return BodyCapsules(
        names=tuple(names),
        joints=np.array(joints, np.int64),
        endpoints=np.array(ends, np.float32),
        radii=np.array(radii, np.float32),
    )


def select_capsules(capsules: BodyCapsules, keep: np.ndarray) -> BodyCapsules:
    """The capsules where ``keep`` (K,) bool is true."""
    keep = np.asarray(keep, bool)
    return BodyCapsules(
        names=tuple(n for n, k in zip(capsules.names, keep) if k),
        joints=capsules.joints[keep],
        endpoints=capsules.endpoints[keep],
        radii=capsules.radii[keep],
    )


def is_arm(name: str) -> bool:
    """Whether a capsule name belongs to an arm (upper arm or forearm)."""
    return "Arm" in name


def arms_collide(shape: BodyShape, garment_top: float, arm_colliders: bool | None) -> bool:
    """Whether the arms collide: as asked (``arm_colliders``), or when that is None, when the
    garment reaches above the chest (``garment_top``, its highest rest-pose height, metres)."""
    if arm_colliders is not None:
        return bool(arm_colliders)
    return garment_top > CHEST_LEVEL * shape.height


def garment_capsules(
    skeleton: Skeleton, shape: BodyShape, garment_top: float, arm_colliders: bool | None
) -> BodyCapsules:
    """The capsules a garment collides with: :func:`body_capsules`, without the arms unless
    :func:`arms_collide` says so."""
    capsules = body_capsules(skeleton, shape)
    if arms_collide(shape, garment_top, arm_colliders):
        return capsules
    return select_capsules(capsules, [not is_arm(n) for n in capsules.names])


def pose_capsules(capsules: BodyCapsules, transforms: np.ndarray) -> np.ndarray:
    """Posed capsule end points.

    Parameters
    ----------
    capsules : BodyCapsules
    transforms : (S, J, 4, 4) float
        Skinning transforms (:func:`core.skeleton.skinning_transforms`).

    Returns
    -------
    (S, K, 2, 3) float32
        Radii do not change with the pose.
    """
    m = np.asarray(transforms, np.float64)
    if m.ndim != 4 or m.shape[2:] != (4, 4) or m.shape[1] <= capsules.joints.max(initial=-1):
        raise InputError(f"transforms must be (S, J, 4, 4) for this skeleton, got {m.shape}")
    m = m[:, capsules.joints]  # (S, K, 4, 4)
    e = capsules.endpoints.astype(np.float64)
    out = np.einsum("skab,kcb->skca", m[..., :3, :3], e) + m[:, :, None, :3, 3]
    return out.astype(np.float32)


def posed_capsules_for(body, motion) -> np.ndarray:
    """Capsule end points of ``body`` for every frame of ``motion``: (T, K, 2, 3) float32.

    ``body`` is a :class:`core.body.mannequin.Body`; ``motion`` is what
    :func:`core.body.skinning.motion_arrays` takes.
    """
    rotations, root = motion_arrays(body.skeleton, motion)
    pos, rot = forward_kinematics(body.skeleton, rotations, root)
    return pose_capsules(body.capsules, skinning_transforms(body.skeleton, pos, rot))


def posed_garment_capsules(
    shape: BodyShape,
    rotations: np.ndarray,
    root_positions: np.ndarray,
    garment_top: float,
    arm_colliders: bool | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The capsules a garment collides with (:func:`garment_capsules`), posed per frame.

    Parameters
    ----------
    shape : BodyShape
    rotations : (T, J, 3, 3) float
    root_positions : (T, 3) float
        A motion on the mannequin's joints.
    garment_top : float
        Highest rest-pose height of the garment, metres.
    arm_colliders : bool or None
        :attr:`core.sim.SimConfig.arm_colliders`.

    Returns
    -------
    ends : (T, K, 2, 3) float32
    radii : (K,) float32
    """
    skeleton = mannequin_skeleton(shape)
    capsules = garment_capsules(skeleton, shape, garment_top, arm_colliders)
    pos, rot = forward_kinematics(skeleton, rotations, root_positions)
    return pose_capsules(capsules, skinning_transforms(skeleton, pos, rot)), capsules.radii


def simulation_colliders(
    shape: BodyShape,
    motion,
    garment_top: float,
    arm_colliders: bool | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The capsules the cloth simulation collides with, posed for every frame of ``motion``.

    The project's one body collider (:mod:`core.body.colliders`), with the simulation's rule
    for the arms (:func:`core.body.colliders.arms_collide`): they collide only when asked to
    (``arm_colliders``) or, when that is None, when the garment reaches above the chest.

    Parameters
    ----------
    shape : BodyShape
    motion : core.motion.Motion on the mannequin's joints, T frames
    garment_top : float
        Highest rest-pose height (metres) of the garment (the proxy's rest positions).
    arm_colliders : bool or None
        :attr:`core.sim.SimConfig.arm_colliders`.

    Returns
    -------
    ends : (T, K, 2, 3) float32
        Posed capsule end points.
    radii : (K,) float32
    """
    rotations, roots = motion_arrays(mannequin_skeleton(shape), motion)
    return posed_garment_capsules(shape, rotations, roots, garment_top, arm_colliders)


def _to_segments(p: np.ndarray, a: np.ndarray, b: np.ndarray):
    """(r, s): the offsets (..., 3) from the segments' closest points to ``p``, and those
    points' positions along the segments (...) in [0, 1]."""
    ab = b - a
    s = np.clip(((p - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-20), 0.0, 1.0)
    return p - (a + s[..., None] * ab), s


def segment_distances(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The distances (...) of :func:`closest_on_segments` alone, the same numbers to the bit."""
    r = _to_segments(p, a, b)[0]
    return np.sqrt((r * r).sum(-1))


def closest_on_segments(p: np.ndarray, a: np.ndarray, b: np.ndarray):
    """Points ``p`` against segments ``a -> b`` (all (..., 3), broadcast together).

    Returns
    -------
    d : (...) distances to the segments
    n : (..., 3) unit directions from the closest points to ``p``
    s : (...) the closest points' positions along the segments, in [0, 1]
    """
    r, s = _to_segments(p, a, b)
    d = np.sqrt((r * r).sum(-1))
    return d, r / np.maximum(d, 1e-12)[..., None], s


def capsule_distance(points: np.ndarray, endpoints: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Signed distance from points to the union of capsules (negative inside).

    Parameters
    ----------
    points : (N, 3) float
    endpoints : (K, 2, 3) float
    radii : (K,) float

    Returns
    -------
    (N,) float32
    """
    p = np.asarray(points, np.float64)
    e = np.asarray(endpoints, np.float64)
    r = np.asarray(radii, np.float64)
    out = np.full(len(p), np.inf)
    if not len(p):
        return out.astype(np.float32)
    # A point is no nearer a segment than its distance to the segment's middle less half its
    # length: each capsule measures only the points that bound lets it be nearer than the
    # nearest so far (1 nm of slack for rounding), the nearest capsules first. The minimum is
    # the same, to the bit, as measuring every point against every capsule.
    mid = 0.5 * (e[:, 0] + e[:, 1])
    half = 0.5 * np.linalg.norm(e[:, 1] - e[:, 0], axis=1)
    order = np.argsort(np.linalg.norm(mid - p.mean(0), axis=1) - half - r)
    for k in order:  # one capsule at a time: (N, 3) arrays, no (N, K, 3) temporaries
        lower = np.sqrt(((p - mid[k]) ** 2).sum(1)) - half[k] - r[k]
        i = np.flatnonzero(lower - 1e-9 < out)
        out[i] = np.minimum(out[i], segment_distances(p[i], e[k, 0], e[k, 1]) - r[k])
    return out.astype(np.float32)


#: Default distance (metres) kept between a pushed vertex and the capsule surface.
DEFAULT_MARGIN_M = 0.002


def _capsule_fallback(axis: np.ndarray) -> np.ndarray:
    """A unit direction perpendicular to each capsule axis (..., 3); +Y for point capsules."""
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    unit = np.where(norm > 1e-12, axis / np.maximum(norm, 1e-12), 0.0)
    helper = np.where(np.abs(unit[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    perp = np.cross(unit, helper)
    pn = np.linalg.norm(perp, axis=-1, keepdims=True)
    return np.where(pn > 1e-12, perp / np.maximum(pn, 1e-12), [0.0, 1.0, 0.0])


def push_out_of_capsules(
    vertices: np.ndarray,
    capsules: np.ndarray,
    radii: np.ndarray,
    margin: float = DEFAULT_MARGIN_M,
    iterations: int = 2,
) -> np.ndarray:
    """Move vertices that lie inside a capsule (or within ``margin`` of it) onto its surface.

    Each vertex inside goes radially out from its closest point on the capsule axis to
    distance ``radius + margin``. Capsules are applied one after another, ``iterations`` times
    over, so a vertex pushed into a neighbouring capsule is pushed again.

    Parameters
    ----------
    vertices : (T, V, 3) or (V, 3) float
    capsules : (T, K, 2, 3) or (K, 2, 3) float
        Segment end points of each capsule, per frame (the unbatched forms go together).
    radii : (K,) float
    margin : float
        Metres kept outside the surface.
    iterations : int

    Returns
    -------
    Same shape as ``vertices``, float32.
    """
    v = np.asarray(vertices, np.float64)
    caps = np.asarray(capsules, np.float64)
    radii = np.asarray(radii, np.float64)
    single = v.ndim == 2
    if single:
        v, caps = v[None], caps[None]
    if v.ndim != 3 or v.shape[-1] != 3:
        raise ValueError(f"vertices must be (T, V, 3) or (V, 3), got {np.shape(vertices)}")
    if caps.ndim != 4 or caps.shape[0] != v.shape[0] or caps.shape[2:] != (2, 3):
        raise ValueError(
            f"capsules must be ({v.shape[0]}, K, 2, 3) to match vertices, got {np.shape(capsules)}"
        )
    if radii.shape != (caps.shape[1],) or not (radii >= 0).all():
        raise ValueError(f"radii must be ({caps.shape[1]},) and >= 0, got {radii.shape}")
    if not (np.isfinite(caps).all() and np.isfinite(radii).all()):
        raise ValueError("capsules or radii contain NaN or infinite values")
    v = v.copy()
    a, b = caps[:, :, 0], caps[:, :, 1]  # (T, K, 3)
    ab = b - a
    ab2 = np.einsum("tki,tki->tk", ab, ab)
    fallback = _capsule_fallback(ab)
    for _ in range(iterations):
        for k in range(caps.shape[1]):
            ap = v - a[:, k, None]  # (T, V, 3)
            denom = np.where(ab2[:, k] > 1e-24, ab2[:, k], 1.0)[:, None]
            s = np.clip(np.einsum("tvi,ti->tv", ap, ab[:, k]) / denom, 0.0, 1.0)
            closest = a[:, k, None] + s[..., None] * ab[:, k, None]
            d = v - closest
            dist = np.linalg.norm(d, axis=-1)
            target = radii[k] + margin
            inside = dist < target
            if not inside.any():
                continue
            safe = np.maximum(dist, 1e-12)[..., None]
            direction = np.where(dist[..., None] > 1e-12, d / safe, fallback[:, k, None])
            v = np.where(inside[..., None], closest + target * direction, v)
    v = v.astype(np.float32)
    return v[0] if single else v


def penetration_depths(
    positions: np.ndarray, capsule_ends: np.ndarray, radii: np.ndarray
) -> np.ndarray:
    """Depth (metres, >= 0) of each vertex inside the capsules, per frame.

    Parameters
    ----------
    positions : (T, N, 3) float
    capsule_ends : (T, K, 2, 3) float, posed capsules at the same frames
    radii : (K,) float

    Returns
    -------
    (T, N) float32
    """
    out = np.empty(positions.shape[:2], np.float32)
    for t in range(len(positions)):
        out[t] = np.maximum(-capsule_distance(positions[t], capsule_ends[t], radii), 0.0)
    return out
