"""Joint2Coarse inputs: canonical joint order, the root (heading) frame, the motion descriptor.

Everything here is numpy, float64 inside and float32 out, so the batch path and the streaming
path (:class:`training.joint2coarse.predict.Joint2CoarseStream`) run the same arithmetic.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from core.errors import InputError
from core.motion.motion import Motion
from core.skeleton import CANONICAL_JOINTS, ROOT_JOINT, forward_kinematics

#: Joint order of every Joint2Coarse joint array: the root first, then the 19 canonical joints.
JOINT2COARSE_JOINTS: tuple[str, ...] = (ROOT_JOINT, *CANONICAL_JOINTS)
#: Joints per frame in a joint array (root + 19).
NUM_JOINTS = len(JOINT2COARSE_JOINTS)


def canonical_joint_order(
    positions: np.ndarray, names: Sequence[str], source: str = ""
) -> np.ndarray:
    """Reorder joint positions to the root + :data:`CANONICAL_JOINTS` order.

    Parameters
    ----------
    positions : (T, J, 3) float
        Joint positions in the order of ``names`` (e.g. ``Motion.joint_positions()`` on the
        mannequin, whose order is Hips, Spine, Spine1, ...).
    names : J str
    source : str
        File or clip name for the error message.

    Returns
    -------
    (T, 20, 3) float32
    """
    positions = np.asarray(positions)
    names = list(names)
    if positions.ndim != 3 or positions.shape[1:] != (len(names), 3):
        raise InputError(
            f"joint positions must be (T, {len(names)}, 3) for {len(names)} names, "
            f"got {positions.shape}",
            source or None,
        )
    missing = [n for n in JOINT2COARSE_JOINTS if n not in names]
    if missing:
        raise InputError(f"skeleton lacks joints {missing} needed by Joint2Coarse", source or None)
    index = [names.index(n) for n in JOINT2COARSE_JOINTS]
    return positions[:, index].astype(np.float32)


def joint2coarse_inputs(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """The two joint arrays Joint2Coarse takes, from a clip on a canonical-named skeleton.

    Returns
    -------
    joints : (T, 20, 3) float32
        World positions, root then :data:`CANONICAL_JOINTS`.
    root_rotations : (T, 3, 3) float32
        World rotation of the root joint.
    """
    names = motion.skeleton.names
    if ROOT_JOINT not in names:
        raise InputError(f"skeleton has no root joint {ROOT_JOINT!r}", motion.name or None)
    positions, rotations = forward_kinematics(
        motion.skeleton, motion.rotations, motion.root_positions
    )
    joints = canonical_joint_order(positions, names, motion.name)
    return joints, rotations[:, names.index(ROOT_JOINT)].astype(np.float32)


def check_joint_inputs(joints: np.ndarray, root_rotations: np.ndarray, source: str = "") -> int:
    """Validate a (joints, root_rotations) pair; return T. Raises :class:`InputError`."""
    joints = np.asarray(joints)
    root_rotations = np.asarray(root_rotations)
    if joints.ndim != 3 or joints.shape[1:] != (NUM_JOINTS, 3):
        raise InputError(
            f"joints must be (T, {NUM_JOINTS}, 3) (root + 19 canonical joints), got {joints.shape}",
            source or None,
        )
    t = joints.shape[0]
    if root_rotations.shape != (t, 3, 3):
        raise InputError(
            f"root_rotations must be ({t}, 3, 3) to match joints, got {root_rotations.shape}",
            source or None,
        )
    if t == 0:
        raise InputError("the clip has no frames", source or None)
    if not np.isfinite(joints).all():
        raise InputError("joints contain NaN or infinite values", source or None)
    if not np.isfinite(root_rotations).all():
        raise InputError("root_rotations contain NaN or infinite values", source or None)
    return t


def heading_rotations(root_rotations: np.ndarray) -> np.ndarray:
    """The yaw part of root rotations: rotation about +Y only.

    The yaw is the twist about Y of the swing-twist split ``R = Ry(yaw) @ swing`` (swing about
    a horizontal axis): ``yaw = atan2(R[0,2] - R[2,0], R[0,0] + R[2,2])``. Unlike projecting the
    facing direction, it stays continuous when the body tilts past 90 degrees.

    Parameters
    ----------
    root_rotations : (..., 3, 3) float

    Returns
    -------
    (..., 3, 3) float64
    """
    r = np.asarray(root_rotations, np.float64)
    yaw = np.arctan2(r[..., 0, 2] - r[..., 2, 0], r[..., 0, 0] + r[..., 2, 2])
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros(r.shape, np.float64)
    out[..., 0, 0] = c
    out[..., 0, 2] = s
    out[..., 1, 1] = 1.0
    out[..., 2, 0] = -s
    out[..., 2, 2] = c
    return out


def to_root_frame(points: np.ndarray, origin: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """World points into the root frame: ``heading^T (p - origin)``.

    Parameters
    ----------
    points : (T, N, 3) float
    origin : (T, 3) float
    heading : (T, 3, 3) float

    Returns
    -------
    (T, N, 3) float64
    """
    d = np.asarray(points, np.float64) - np.asarray(origin, np.float64)[:, None]
    return np.matmul(d, heading)  # row vectors: (H^T d)^T = d^T H; BLAS, unlike einsum


def from_root_frame(points: np.ndarray, origin: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Root-frame points back to world: ``heading p + origin``. Shapes as :func:`to_root_frame`."""
    p = np.matmul(np.asarray(points, np.float64), np.swapaxes(heading, -1, -2))
    return p + np.asarray(origin, np.float64)[:, None]


def history_indices(num_frames: int, window: int, stride: int) -> np.ndarray:
    """Frame index of each descriptor sample: ``max(t - k * stride, 0)``.

    Returns
    -------
    (T, K) int64 with ``K = ceil(window / stride)``; column 0 is frame t itself.
    """
    k = -(-window // stride)
    idx = np.arange(num_frames)[:, None] - stride * np.arange(k)[None, :]
    return np.maximum(idx, 0)


def descriptor_from_history(
    history: np.ndarray, origin: np.ndarray, heading: np.ndarray
) -> np.ndarray:
    """Descriptors from already-gathered joint histories.

    Parameters
    ----------
    history : (T, K, 19, 3) float
        World positions of the 19 canonical joints at the K sampled frames (current first).
    origin : (T, 3) float
        Root position at frame t.
    heading : (T, 3, 3) float
        Heading rotation at frame t (:func:`heading_rotations`).

    Returns
    -------
    (T, K * 19 * 3) float32
        Sample-major, then joint, then x, y, z.
    """
    t, k = history.shape[:2]
    local = to_root_frame(history.reshape(t, -1, 3), origin, heading)
    return local.reshape(t, -1).astype(np.float32)


def motion_descriptors(
    joints: np.ndarray, root_rotations: np.ndarray, window: int, stride: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The motion descriptor of every frame, and the root frame it is expressed in.

    Frames before the clip start repeat frame 0.

    Parameters
    ----------
    joints : (T, 20, 3) float
        World positions, root then :data:`CANONICAL_JOINTS`.
    root_rotations : (T, 3, 3) float
    window, stride : int
        See :class:`Joint2CoarseConfig`.

    Returns
    -------
    descriptors : (T, ceil(window / stride) * 57) float32
    origin : (T, 3) float64
        Root position per frame.
    heading : (T, 3, 3) float64
        Root heading (yaw about +Y) per frame.
    """
    joints = np.asarray(joints, np.float64)
    idx = history_indices(len(joints), window, stride)
    origin = joints[:, 0]
    heading = heading_rotations(root_rotations)
    return descriptor_from_history(joints[idx][:, :, 1:], origin, heading), origin, heading
