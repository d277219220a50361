"""Skeletons, forward kinematics, and the canonical 19-joint rig the whole studio speaks.

Conventions (see DESIGN): metres, Y up, right-handed; a character faces +Z with its left side
towards +X. Rotations are 3x3 matrices, local to the parent joint; the rest pose is all
identities, so the offsets alone describe it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The 19 joints of the paper's Mixamo rig, in the order every array uses.
CANONICAL_JOINTS: tuple[str, ...] = (
    "Head", "Neck", "Spine2", "Spine1", "Spine",
    "RightShoulder", "RightArm", "RightForeArm", "RightHand",
    "LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand",
    "LeftUpLeg", "LeftLeg", "LeftFoot",
    "RightUpLeg", "RightLeg", "RightFoot",
)  # fmt: skip
#: The root, kept beside the 19 for root-relative descriptors.
ROOT_JOINT = "Hips"


@dataclass(frozen=True)
class Skeleton:
    """A joint hierarchy in its rest pose.

    Attributes
    ----------
    names : tuple of J str
        Joint names; joint 0 is the root. Parents come before children.
    parents : (J,) int64
        Parent index per joint, -1 for the root.
    offsets : (J, 3) float32
        Rest offset of each joint from its parent, in the parent's frame (metres once
        normalised). The root's offset is its rest position.
    end_sites : (J, 3) float32
        Offset of the joint's end site, or zeros where it has none (BVH ``End Site``).
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: np.ndarray

    def __post_init__(self) -> None:
        j = len(self.names)
        if self.parents.shape != (j,) or self.offsets.shape != (j, 3):
            raise ValueError(
                f"skeleton arrays disagree: {j} names, parents {self.parents.shape}, "
                f"offsets {self.offsets.shape}"
            )
        if self.end_sites.shape != (j, 3):
            raise ValueError(f"end_sites must be ({j}, 3), got {self.end_sites.shape}")
        if j and self.parents[0] != -1:
            raise ValueError("joint 0 must be the root (parent -1)")
        for i, p in enumerate(self.parents[1:], start=1):
            if not 0 <= p < i:
                raise ValueError(f"joint {self.names[i]!r} has parent {p}: parents must come first")

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def children(self, j: int) -> list[int]:
        return [i for i, p in enumerate(self.parents) if p == j]

    def rest_positions(self) -> np.ndarray:
        """World positions of the joints in the rest pose: (J, 3) float32."""
        pos = np.zeros((self.num_joints, 3), np.float64)
        for j, p in enumerate(self.parents):
            pos[j] = self.offsets[j] if p < 0 else pos[p] + self.offsets[j]
        return pos.astype(np.float32)

    def bone_lengths(self) -> np.ndarray:
        """Length of the bone from each joint's parent to the joint: (J,) float32 (root: 0)."""
        lengths = np.linalg.norm(self.offsets, axis=1).astype(np.float32)
        lengths[self.parents < 0] = 0.0
        return lengths


def forward_kinematics(
    skeleton: Skeleton, rotations: np.ndarray, root_positions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World transforms of every joint for every frame.

    Parameters
    ----------
    skeleton : Skeleton with J joints
    rotations : (T, J, 3, 3) float
        Local rotation of each joint relative to its parent.
    root_positions : (T, 3) float
        World position of the root joint.

    Returns
    -------
    positions : (T, J, 3) float32
        World joint positions.
    global_rotations : (T, J, 3, 3) float32
        World orientation of each joint frame.
    """
    rotations = np.asarray(rotations, np.float64)
    root_positions = np.asarray(root_positions, np.float64)
    t, j = rotations.shape[:2]
    if rotations.shape != (t, j, 3, 3) or j != skeleton.num_joints:
        raise ValueError(
            f"rotations must be (T, {skeleton.num_joints}, 3, 3), got {rotations.shape}"
        )
    if root_positions.shape != (t, 3):
        raise ValueError(f"root_positions must be ({t}, 3), got {root_positions.shape}")
    g_rot = np.empty_like(rotations)
    pos = np.empty((t, j, 3))
    offsets = skeleton.offsets.astype(np.float64)
    for i, p in enumerate(skeleton.parents):
        if p < 0:
            g_rot[:, i] = rotations[:, i]
            pos[:, i] = root_positions
        else:
            g_rot[:, i] = g_rot[:, p] @ rotations[:, i]
            pos[:, i] = pos[:, p] + g_rot[:, p] @ offsets[i]
    return pos.astype(np.float32), g_rot.astype(np.float32)


def skinning_transforms(
    skeleton: Skeleton, positions: np.ndarray, global_rotations: np.ndarray
) -> np.ndarray:
    """Per-joint 4x4 transforms taking rest-pose points to posed points (for LBS).

    Parameters
    ----------
    positions : (T, J, 3) float
    global_rotations : (T, J, 3, 3) float
        Outputs of :func:`forward_kinematics`.

    Returns
    -------
    (T, J, 4, 4) float32
        ``M = [R | p - R @ rest_p]``: a point x attached rigidly to joint j in the rest pose
        lands at ``R @ x + (p - R @ rest_p)``.
    """
    rest = skeleton.rest_positions().astype(np.float64)
    r = np.asarray(global_rotations, np.float64)
    t = np.asarray(positions, np.float64) - np.einsum("tjab,jb->tja", r, rest)
    m = np.zeros(r.shape[:2] + (4, 4))
    m[..., :3, :3] = r
    m[..., :3, 3] = t
    m[..., 3, 3] = 1.0
    return m.astype(np.float32)


def rotation_about(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices about unit ``axis`` (3,) by ``angle`` (...,) radians: (..., 3, 3)."""
    axis = np.asarray(axis, np.float64)
    axis = axis / np.linalg.norm(axis)
    angle = np.asarray(angle, np.float64)
    x, y, z = axis
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)
