"""Collision capsules for the cloth simulator, fitted just inside the mannequin's skin.

Each capsule follows one bone: its rest endpoints are rigidly attached to the bone's joint,
so posing is ``p_j + R_j (x - rest_j)``, the same rigid transform linear blend skinning gives
a vertex weighted fully to that joint. The torso is a stack of left-right capsules (an
ellipse is well covered by stadium shapes), limbs are chains of capsules along the bones
(split where they taper). Radii are fitted to the mesh: the largest radius that keeps the
capsule ``margin`` inside the surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.body.shape import BodyShape
from core.errors import InputError
from core.skeleton import Skeleton

#: Gap between a capsule and the skin, as a fraction of the height (3.4 mm at 1.70 m).
MARGIN_FRACTION = 0.002
#: Horizontal torso capsules between the crotch and the shoulders.
TORSO_CAPSULES = 10
_SAMPLES = 24  # points along a capsule's axis when fitting its radius


@dataclass(frozen=True)
class Capsules:
    """Capsules attached to a skeleton's joints.

    Attributes
    ----------
    names : tuple of K str
    joints : (K, 2) int64
        The bone each capsule follows, as (joint, child joint) indices; the first joint's
        transform carries it. For a bone that ends in an end site the child is the joint itself.
    endpoints : (K, 2, 3) float32
        Rest-pose endpoints, metres.
    radii : (K,) float32
    rest_joints : (J, 3) float32
        Rest positions of the skeleton's joints (what posing subtracts).
    """

    names: tuple[str, ...]
    joints: np.ndarray
    endpoints: np.ndarray
    radii: np.ndarray
    rest_joints: np.ndarray

    def __post_init__(self) -> None:
        k = len(self.names)
        if self.joints.shape != (k, 2) or self.endpoints.shape != (k, 2, 3):
            raise ValueError(f"capsule arrays disagree with {k} names")
        if self.radii.shape != (k,) or (self.radii <= 0).any():
            raise ValueError("capsule radii must be (K,) and positive")

    @property
    def num_capsules(self) -> int:
        return len(self.names)


def fit_capsules(
    vertices: np.ndarray, faces: np.ndarray, skeleton: Skeleton, shape: BodyShape
) -> Capsules:
    """Capsules for a mannequin mesh, each as thick as fits ``MARGIN_FRACTION`` inside it.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
        Closed, outward-oriented rest mesh.
    skeleton : Skeleton
        ``mannequin_skeleton(shape)``.
    shape : BodyShape
    """
    from core.body.mannequin import torso_range, torso_sections

    h = shape.height
    pos = skeleton.rest_positions().astype(np.float64)
    end = skeleton.end_sites.astype(np.float64)
    ix = skeleton.index
    names: list[str] = []
    joints: list[tuple[int, int]] = []
    segs: list[np.ndarray] = []

    def add(name: str, joint: str, child: str | None, a, b) -> None:
        names.append(name)
        joints.append((ix(joint), ix(child) if child else ix(joint)))
        segs.append(np.array([a, b], np.float64))

    # Torso: left-right capsules stacked from just above the crotch to below the shoulders.
    # Per level, the length that gives the fattest stadium (4 L r + pi r^2) inside the skin.
    y0, y1 = torso_range(shape)
    ys = np.linspace(y0 + 0.025 * h, y1 - 0.04 * h, TORSO_CAPSULES)
    a, b, zc = torso_sections(shape, ys)
    fractions = np.array([0.2, 0.45, 0.7, 0.95])
    cand = []
    for ai, bi, y, zi in zip(a, b, ys, zc):
        for fr in fractions:
            half = fr * max(ai - 0.5 * min(ai, bi), 1e-4)
            cand.append(((-half, y, zi), (half, y, zi)))
    cand_segs, cand_r, cand_ok = _fit_radii(
        vertices, faces, np.asarray(cand, np.float64), MARGIN_FRACTION * h
    )
    cand_segs = cand_segs.reshape(len(ys), len(fractions), 2, 3)
    half_len = np.linalg.norm(cand_segs[:, :, 1] - cand_segs[:, :, 0], axis=2) / 2
    r = cand_r.reshape(len(ys), len(fractions))
    area = np.where(cand_ok.reshape(r.shape), 4 * half_len * r + np.pi * r**2, -1.0)
    best = area.argmax(axis=1)
    spine = ["Hips", "Spine", "Spine1", "Spine2"]
    spine_y = [pos[ix(n), 1] for n in spine[1:]]
    for i, y in enumerate(ys):
        k = int(np.searchsorted(spine_y, y))
        child = spine[k + 1] if k + 1 < len(spine) else "Neck"
        seg = cand_segs[i, best[i]]
        add(f"Torso{i}", spine[k], child, seg[0], seg[1])
    add("Neck", "Neck", "Head", pos[ix("Neck")], pos[ix("Head")])
    head = pos[ix("Head")] + end[ix("Head")] * np.array([[0.35], [0.65]])
    add("Head", "Head", None, head[0], head[1])
    for side in ("Left", "Right"):
        s, a_, fa, hd = (pos[ix(f"{side}{n}")] for n in ("Shoulder", "Arm", "ForeArm", "Hand"))
        add(f"{side}Shoulder", f"{side}Shoulder", f"{side}Arm", s, a_)
        for k, (p, q) in enumerate(_split(a_, fa, 2)):
            add(f"{side}UpperArm{k}", f"{side}Arm", f"{side}ForeArm", p, q)
        for k, (p, q) in enumerate(_split(fa, hd, 2)):
            add(f"{side}ForeArm{k}", f"{side}ForeArm", f"{side}Hand", p, q)
        add(f"{side}Hand", f"{side}Hand", None, hd, hd + 0.8 * end[ix(f"{side}Hand")])
        up, kn, ft = (pos[ix(f"{side}{n}")] for n in ("UpLeg", "Leg", "Foot"))
        for k, (p, q) in enumerate(_split(up, kn, 4)):
            add(f"{side}Thigh{k}", f"{side}UpLeg", f"{side}Leg", p, q)
        for k, (p, q) in enumerate(_split(kn, ft, 2)):
            add(f"{side}Shin{k}", f"{side}Leg", f"{side}Foot", p, q)
        toe = ft + end[ix(f"{side}Foot")]
        heel = np.array([ft[0], 0.5 * ft[1], ft[2] - 0.02 * h])
        tip = np.array([toe[0], 0.4 * ft[1], toe[2] - 0.035 * h])
        add(f"{side}Foot", f"{side}Foot", None, heel, tip)
    margin = MARGIN_FRACTION * h
    segs_arr, radii, keep = _fit_radii(vertices, faces, np.stack(segs), margin)
    return Capsules(
        names=tuple(n for n, k in zip(names, keep) if k),
        joints=np.asarray(joints, np.int64)[keep],
        endpoints=segs_arr[keep].astype(np.float32),
        radii=radii[keep].astype(np.float32),
        rest_joints=pos.astype(np.float32),
    )


def _split(a: np.ndarray, b: np.ndarray, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    t = np.linspace(0, 1, n + 1)
    return [(a + t[i] * (b - a), a + t[i + 1] * (b - a)) for i in range(n)]


def _fit_radii(vertices, faces, segs: np.ndarray, margin: float):
    """Largest radius per segment that stays ``margin`` inside; segments poking out of the
    mesh are shortened towards their middle (and dropped if nothing fits).

    Returns (segments (K, 2, 3), radii (K,), keep (K,) bool).
    """
    import igl

    v = np.ascontiguousarray(vertices, np.float64)
    f = np.ascontiguousarray(faces, np.int64)
    tree = igl.AABB()
    tree.init(v, f)
    segs = segs.copy()
    radii = np.zeros(len(segs))
    keep = np.zeros(len(segs), bool)
    t = np.linspace(0, 1, _SAMPLES)
    todo = np.arange(len(segs))
    for _ in range(6):
        pts = segs[todo, :1] + t[None, :, None] * (segs[todo, 1:] - segs[todo, :1])
        q = np.ascontiguousarray(pts.reshape(-1, 3))
        dist = np.sqrt(tree.squared_distance(v, f, q)[0])
        inside = igl.fast_winding_number(v, f, q) > 0.5
        sd = np.where(inside, -dist, dist).reshape(len(todo), _SAMPLES)
        r = (-sd).min(axis=1) - margin
        ok = (sd < 0).all(axis=1) & (r > margin)
        radii[todo[ok]] = r[ok]
        keep[todo[ok]] = True
        todo = todo[~ok]
        if len(todo) == 0:
            break
        mid = segs[todo].mean(axis=1, keepdims=True)
        segs[todo] = mid + 0.6 * (segs[todo] - mid)
    return segs, radii, keep


def pose_capsules(
    capsules: Capsules, positions: np.ndarray, global_rotations: np.ndarray
) -> np.ndarray:
    """Posed capsule endpoints.

    Parameters
    ----------
    capsules : Capsules
    positions : (T, J, 3) float
    global_rotations : (T, J, 3, 3) float
        Joint world positions and orientations, from :func:`core.skeleton.forward_kinematics`.

    Returns
    -------
    (T, K, 2, 3) float32
        Radii do not change with the pose.
    """
    p = np.asarray(positions, np.float64)
    r = np.asarray(global_rotations, np.float64)
    j = len(capsules.rest_joints)
    if p.ndim != 3 or p.shape[1:] != (j, 3) or r.shape != p.shape + (3,):
        raise InputError(
            f"positions must be (T, {j}, 3) and rotations (T, {j}, 3, 3); "
            f"got {p.shape} and {r.shape}"
        )
    carrier = capsules.joints[:, 0]
    local = capsules.endpoints.astype(np.float64) - capsules.rest_joints[carrier][:, None, :]
    out = p[:, carrier, None, :] + np.einsum("tkab,knb->tkna", r[:, carrier], local)
    return out.astype(np.float32)


def transform_capsules(capsules: Capsules, transforms: np.ndarray) -> np.ndarray:
    """Posed capsule endpoints from skinning transforms (what LBS applies to the skin).

    Parameters
    ----------
    capsules : Capsules
    transforms : (T, J, 4, 4) float
        From :func:`core.skeleton.skinning_transforms`.

    Returns
    -------
    (T, K, 2, 3) float32
        The same as :func:`pose_capsules` on the FK that made ``transforms``.
    """
    m = np.asarray(transforms, np.float64)
    j = len(capsules.rest_joints)
    if m.ndim != 4 or m.shape[1:] != (j, 4, 4):
        raise InputError(f"transforms must be (T, {j}, 4, 4), got {m.shape}")
    mk = m[:, capsules.joints[:, 0]]  # (T, K, 4, 4)
    e = capsules.endpoints.astype(np.float64)
    out = np.einsum("tkab,knb->tkna", mk[..., :3, :3], e) + mk[:, :, None, :3, 3]
    return out.astype(np.float32)


def posed_capsules_for(body, motion) -> np.ndarray:
    """Capsule endpoints of ``body`` for every frame of ``motion``: (T, K, 2, 3) float32.

    ``motion`` is what :func:`core.body.skinning.pose_body` takes.
    """
    from core.body.skinning import _motion_arrays
    from core.skeleton import forward_kinematics

    rotations, root = _motion_arrays(body.skeleton, motion)
    pos, rot = forward_kinematics(body.skeleton, rotations, root)
    return pose_capsules(body.capsules, pos, rot)


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
    a, ab = e[:, 0], e[:, 1] - e[:, 0]
    out = np.full(len(p), np.inf)
    for i0 in range(0, len(p), 4096):
        q = p[i0 : i0 + 4096, None, :] - a[None]
        t = np.clip(np.einsum("nkc,kc->nk", q, ab) / np.maximum((ab * ab).sum(1), 1e-18), 0, 1)
        d = np.linalg.norm(q - t[..., None] * ab[None], axis=2) - np.asarray(radii)[None]
        out[i0 : i0 + 4096] = d.min(axis=1)
    return out.astype(np.float32)
