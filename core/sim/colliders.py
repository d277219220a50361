"""The body as the cloth solver sees it: rigid capsules carried by the mannequin's bones.

Why capsules and not the skinned body mesh: a capsule is an exact, smooth signed-distance
shape, cheap to test a particle against (one segment distance), and it moves rigidly with one
bone, so the solver gets exact poses and velocities every substep. A skinned mesh collider
would need its BVH refitted every substep and gives faceted normals; on CPU that costs more
than the whole cloth solve of a 2k proxy.

The torso is a stack of horizontal capsules (stadium cross-sections) whose widths and depths
follow the mannequin's hip, waist and chest girths (the same ellipse aspects and key heights
as :mod:`core.body.mannequin`); limbs are capsules along their bones; the head a sphere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.body.shape import BodyShape
from core.skeleton import Skeleton

#: Torso key heights (fractions of the height) and which bone carries the torso above each.
_TORSO_KEYS = (0.440, 0.500, 0.630, 0.720, 0.772, 0.805)
_ASPECT = {"hip": 1.45, "waist": 1.38, "chest": 1.32}
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


def _ellipse_perimeter(a: float, b: float) -> float:
    h = ((a - b) / (a + b)) ** 2
    return math.pi * (a + b) * (1 + 3 * h / (10 + math.sqrt(4 - 3 * h)))


def body_capsules(skeleton: Skeleton, shape: BodyShape) -> BodyCapsules:
    """Capsules for the mannequin ``skeleton`` built from ``shape`` (A-pose rest)."""
    h, t = shape.height, shape.thickness
    p = skeleton.rest_positions().astype(np.float64)
    ix = skeleton.index
    keys = {}
    for name, girth in (("hip", shape.hip), ("waist", shape.waist), ("chest", shape.chest)):
        r = _ASPECT[name]
        a = girth / _ellipse_perimeter(1.0, 1.0 / r)
        keys[name] = (a, a / r)
    (ah, bh), (aw, bw), (ac, bc) = keys["hip"], keys["waist"], keys["chest"]
    sw = shape.shoulder_width
    key_a = [0.93 * ah, ah, aw, ac, max(0.97 * ac, 0.42 * sw), max(0.80 * ac, 0.40 * sw)]
    key_b = [0.90 * bh, bh, bw, bc, 0.92 * bc, 0.72 * bc]
    key_z = [-0.004 * h, 0.0, 0.004 * h, 0.012 * h, 0.0, -0.012 * h]
    ys = np.array(_TORSO_KEYS) * h

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


def pose_capsules(capsules: BodyCapsules, transforms: np.ndarray) -> np.ndarray:
    """Posed capsule end points.

    Parameters
    ----------
    transforms : (S, J, 4, 4) float
        Skinning transforms (:func:`core.skeleton.skinning_transforms`).

    Returns
    -------
    (S, K, 2, 3) float32
    """
    m = np.asarray(transforms, np.float64)[:, capsules.joints]  # (S, K, 4, 4)
    e = capsules.endpoints.astype(np.float64)
    out = np.einsum("skab,kcb->skca", m[..., :3, :3], e) + m[:, :, None, :3, 3]
    return out.astype(np.float32)
