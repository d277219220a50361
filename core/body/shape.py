"""Body shape parameters and the mannequin's skeleton built from them."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from core.errors import InputError
from core.skeleton import CANONICAL_JOINTS, ROOT_JOINT, Skeleton

#: The mannequin's joints: the root, then the 19 canonical joints in a parents-first order.
MANNEQUIN_JOINTS: tuple[str, ...] = (
    ROOT_JOINT, "Spine", "Spine1", "Spine2", "Neck", "Head",
    "LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand",
    "RightShoulder", "RightArm", "RightForeArm", "RightHand",
    "LeftUpLeg", "LeftLeg", "LeftFoot",
    "RightUpLeg", "RightLeg", "RightFoot",
)  # fmt: skip
_PARENT = {
    "Spine": ROOT_JOINT, "Spine1": "Spine", "Spine2": "Spine1", "Neck": "Spine2", "Head": "Neck",
    "LeftShoulder": "Spine2", "LeftArm": "LeftShoulder", "LeftForeArm": "LeftArm",
    "LeftHand": "LeftForeArm",
    "RightShoulder": "Spine2", "RightArm": "RightShoulder", "RightForeArm": "RightArm",
    "RightHand": "RightForeArm",
    "LeftUpLeg": ROOT_JOINT, "LeftLeg": "LeftUpLeg", "LeftFoot": "LeftLeg",
    "RightUpLeg": ROOT_JOINT, "RightLeg": "RightUpLeg", "RightFoot": "RightLeg",
}  # fmt: skip
assert set(MANNEQUIN_JOINTS[1:]) == set(CANONICAL_JOINTS)

#: Arms in the rest pose hang this many degrees below horizontal (an A-pose, kind to garments).
REST_ARM_DROP_DEG = 45.0


@dataclass(frozen=True)
class BodyShape:
    """Shape of the mannequin. Lengths in metres; girths are circumferences in metres."""

    height: float = 1.70
    """Standing height, floor to the top of the head."""
    shoulder_width: float = 0.38
    """Distance between the two shoulder joints (RightArm to LeftArm)."""
    chest: float = 0.88
    """Chest girth."""
    waist: float = 0.70
    """Waist girth (at Spine1, the narrowest part of the torso)."""
    hip: float = 0.96
    """Hip girth (at the widest part of the buttocks)."""
    build: float = 0.0
    """Thin (-1) to heavy (+1): scales limb and torso thickness on top of the girths."""

    def __post_init__(self) -> None:
        limits = {
            "height": (0.5, 2.6), "shoulder_width": (0.15, 0.8), "chest": (0.4, 2.0),
            "waist": (0.35, 2.0), "hip": (0.4, 2.2), "build": (-1.0, 1.0),
        }  # fmt: skip
        for name, (lo, hi) in limits.items():
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
                raise InputError(f"body shape {name}={v!r} is outside [{lo}, {hi}]")

    @property
    def thickness(self) -> float:
        """Multiplier on limb radii from ``build``: 0.8 (thin) .. 1.35 (heavy)."""
        return 1.0 + (0.35 if self.build > 0 else 0.2) * self.build

    @staticmethod
    def parse(pairs: list[str] | None, base: BodyShape | None = None) -> BodyShape:
        """Parse ``["height=1.8", "build=0.5"]`` (the CLI's ``--shape k=v ...``)."""
        shape = base or BodyShape()
        names = {f.name for f in fields(BodyShape)}
        updates: dict[str, float] = {}
        for pair in pairs or []:
            key, sep, value = pair.partition("=")
            key = key.strip().replace("-", "_")
            if not sep or key not in names:
                raise InputError(
                    f"bad body shape parameter {pair!r}: use k=v with k in {sorted(names)}"
                )
            try:
                updates[key] = float(value)
            except ValueError:
                raise InputError(f"bad body shape value {pair!r}: not a number") from None
        return replace(shape, **updates)

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


def mannequin_skeleton(shape: BodyShape = BodyShape()) -> Skeleton:
    """The mannequin's rest skeleton for ``shape``: A-pose, facing +Z, feet on the floor.

    Proportions follow standard anthropometric fractions of the height (Drillis and Contini),
    with the shoulders set by ``shoulder_width`` and the hip joints by the hip girth.
    The Head joint sits at the base of the skull; its end site is the top of the head.
    The feet's end sites are the toes, at floor height.
    """
    h = shape.height
    y = {
        "Hips": 0.530 * h, "Spine": 0.580 * h, "Spine1": 0.630 * h, "Spine2": 0.720 * h,
        "Neck": 0.820 * h, "Head": 0.880 * h, "LeftUpLeg": 0.500 * h, "LeftLeg": 0.285 * h,
        "LeftFoot": 0.045 * h,
    }  # fmt: skip
    hip_half = 0.095 * shape.hip  # hip joints sit about 0.2 of the hip girth apart
    arm = np.radians(REST_ARM_DROP_DEG)
    upper, fore, hand = 0.186 * h, 0.146 * h, 0.108 * h
    clav_y = 0.815 * h  # height of the shoulder joints
    pos: dict[str, np.ndarray] = {
        "Hips": np.array([0.0, y["Hips"], 0.0]),
        "Spine": np.array([0.0, y["Spine"], -0.005 * h]),
        "Spine1": np.array([0.0, y["Spine1"], -0.008 * h]),
        "Spine2": np.array([0.0, y["Spine2"], -0.006 * h]),
        "Neck": np.array([0.0, y["Neck"], -0.010 * h]),
        "Head": np.array([0.0, y["Head"], 0.0]),
    }
    for side, sx in (("Left", 1.0), ("Right", -1.0)):
        shoulder = np.array([sx * 0.02 * h, 0.790 * h, -0.004 * h])
        arm_j = np.array([sx * shape.shoulder_width / 2, clav_y, -0.008 * h])
        direction = np.array([sx * np.cos(arm), -np.sin(arm), 0.0])
        pos[f"{side}Shoulder"] = shoulder
        pos[f"{side}Arm"] = arm_j
        pos[f"{side}ForeArm"] = arm_j + upper * direction
        pos[f"{side}Hand"] = arm_j + (upper + fore) * direction
        pos[f"{side}UpLeg"] = np.array([sx * hip_half, y["LeftUpLeg"], 0.0])
        pos[f"{side}Leg"] = np.array([sx * hip_half * 0.95, y["LeftLeg"], 0.005 * h])
        pos[f"{side}Foot"] = np.array([sx * hip_half * 0.9, y["LeftFoot"], -0.005 * h])
    names = MANNEQUIN_JOINTS
    parents = np.array([-1] + [names.index(_PARENT[n]) for n in names[1:]], np.int64)
    offsets = np.stack(
        [pos[n] if p < 0 else pos[n] - pos[names[p]] for n, p in zip(names, parents)]
    ).astype(np.float32)
    end_sites = np.zeros((len(names), 3), np.float32)
    end_sites[names.index("Head")] = (0.0, h - y["Head"], 0.0)
    for side, sx in (("Left", 1.0), ("Right", -1.0)):
        end_sites[names.index(f"{side}Hand")] = hand * np.array([sx * np.cos(arm), -np.sin(arm), 0])
        end_sites[names.index(f"{side}Foot")] = (0.0, -y["LeftFoot"], 0.145 * h)
    return Skeleton(names=names, parents=parents, offsets=offsets, end_sites=end_sites)


# --------------------------------------------------------------------------------------------
# The torso's key sections: one definition for the mannequin mesh and its colliders.

#: Heights (fractions of the standing height) where the girths are measured.
HIP_LEVEL = 0.500
WAIST_LEVEL = 0.630
CHEST_LEVEL = 0.720
#: Bottom (crotch) and top (shoulder) of the torso, fractions of the height.
TORSO_BOTTOM = 0.440
TORSO_TOP = 0.838
#: Width / depth of the torso ellipse at the hip, waist and chest.
TORSO_ASPECT = {"hip": 1.45, "waist": 1.38, "chest": 1.32}
#: Heights of the torso's key sections, fractions of the height (bottom to top).
TORSO_KEY_LEVELS = (TORSO_BOTTOM, HIP_LEVEL, WAIST_LEVEL, CHEST_LEVEL, 0.772, 0.805, TORSO_TOP)


def ellipse_perimeter(a: float, b: float) -> float:
    """Ramanujan's second approximation of the perimeter of an ellipse with semi-axes a, b."""
    h = ((a - b) / (a + b)) ** 2
    return math.pi * (a + b) * (1 + 3 * h / (10 + math.sqrt(4 - 3 * h)))


def torso_keys(
    shape: BodyShape, scale: dict[str, float] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The torso's elliptic key sections, from the girths and the shoulder width.

    At the hip, waist and chest the ellipse has the girth (times ``scale[name]``, the
    mannequin's fitting knob; 1 when None) and the aspect ``TORSO_ASPECT``; the sections
    below and above follow from them.

    Returns
    -------
    y, half_width, half_depth, z_centre : (7,) float64 each
        At the heights ``TORSO_KEY_LEVELS`` (metres).
    """
    h = shape.height
    keys = {}
    for name, girth in (("hip", shape.hip), ("waist", shape.waist), ("chest", shape.chest)):
        r = TORSO_ASPECT[name]
        k = 1.0 if scale is None else scale[name]
        a = girth * k / ellipse_perimeter(1.0, 1.0 / r)
        keys[name] = (a, a / r)
    (ah, bh), (aw, bw), (ac, bc) = keys["hip"], keys["waist"], keys["chest"]
    sw = shape.shoulder_width
    a = np.array(
        [
            0.93 * ah,
            ah,
            aw,
            ac,
            max(0.97 * ac, 0.42 * sw),
            max(0.80 * ac, 0.40 * sw),
            max(0.62 * ac, 0.34 * sw),
        ]
    )
    b = np.array([0.90 * bh, bh, bw, bc, 0.92 * bc, 0.72 * bc, 0.55 * bc])
    zc = np.array([-0.004, 0.0, 0.004, 0.012, 0.0, -0.012, -0.014]) * h
    return np.array(TORSO_KEY_LEVELS) * h, a, b, zc
