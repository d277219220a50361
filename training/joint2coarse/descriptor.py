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


def tilt_rotvecs(root_rotations: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """The root's tilt beyond its heading, ``heading^T root``, as rotation vectors.

    With the heading from :func:`heading_rotations` this is the swing of the swing-twist split:
    the pelvis's pitch and roll, about a horizontal axis, in root-frame coordinates. The angle
    comes from ``atan2(sin, cos)`` (accurate near 0); past 90 degrees the axis comes from the
    symmetric part of the matrix, so the vector stays accurate up to a half turn (upside down),
    where its sign is arbitrary.

    Parameters
    ----------
    root_rotations : (T, 3, 3) float
    heading : (T, 3, 3) float

    Returns
    -------
    (T, 3) float64: unit axis times angle in [0, pi].
    """
    m = np.matmul(np.swapaxes(np.asarray(heading, np.float64), -1, -2), root_rotations)
    v = 0.5 * np.stack(
        [m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], -1
    )  # sin(angle) * axis
    s = np.linalg.norm(v, axis=-1)
    c = np.clip(0.5 * (np.trace(m, axis1=1, axis2=2) - 1.0), -1.0, 1.0)
    angle = np.arctan2(s, c)
    scale = np.ones_like(s)  # angle / sin(angle), 1 in the limit of no tilt
    turned = s > 0.0
    scale[turned] = angle[turned] / s[turned]
    out = v * scale[:, None]
    wide = c < 0.0  # past 90 degrees sin(angle) loses the axis: (sym - c I) = (1 - c) k k^T
    if wide.any():
        sym = 0.5 * (m[wide] + np.swapaxes(m[wide], -1, -2)) - c[wide, None, None] * np.eye(3)
        col = np.argmax(np.diagonal(sym, axis1=1, axis2=2), axis=-1)
        axis = sym[np.arange(len(sym)), :, col]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        axis *= np.where(np.sum(axis * v[wide], -1) < 0.0, -1.0, 1.0)[:, None]
        out[wide] = axis * angle[wide, None]
    return out


def follow_weights(heights: np.ndarray, top: float) -> np.ndarray:
    """How much of the root's tilt each proxy vertex's output frame takes: ``top`` at the
    highest vertex, falling linearly with height to 0 at the lowest.

    Parameters
    ----------
    heights : (Vc,) float
        Root-frame height of each vertex in a typical shape (the training shapes' mean).
    top : float
        Weight at the top, in [0, 1] (:attr:`Joint2CoarseConfig.tilt_follow`).

    Returns
    -------
    (Vc,) float32; all ``top`` when every vertex is at one height.
    """
    y = np.asarray(heights, np.float64)
    span = y.max() - y.min()
    if span <= 1e-9:
        return np.full(len(y), top, np.float32)
    return (top * (y - y.min()) / span).astype(np.float32)


def rotate_partially(points: np.ndarray, rotvecs: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    """Rotate each point by its own fraction of its frame's rotation (Rodrigues' formula).

    Parameters
    ----------
    points : (T, N, 3) float
    rotvecs : (T, 3) float
        Axis times angle per frame.
    fractions : (N,) float
        Point n turns by ``fractions[n] * angle`` about the frame's axis.

    Returns
    -------
    (T, N, 3) float64
    """
    p = np.asarray(points, np.float64)
    rotvecs = np.asarray(rotvecs, np.float64)
    angle = np.linalg.norm(rotvecs, axis=-1)
    k = rotvecs / np.where(angle > 0.0, angle, 1.0)[:, None]  # (T, 3) unit axes
    a = np.asarray(fractions, np.float64)[None, :, None] * angle[:, None, None]  # (T, N, 1)
    # k x p and k (k . p) as products with (3, 3) matrices: BLAS, not cross and sum per point.
    skew = np.zeros((len(k), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    skew -= np.swapaxes(skew, -1, -2)
    outer = k[:, :, None] * k[:, None, :]
    cos = np.cos(a)
    along = np.matmul(p, outer)
    return (p - along) * cos + np.matmul(p, np.swapaxes(skew, -1, -2)) * np.sin(a) + along


def to_output_frame(
    points: np.ndarray,
    origin: np.ndarray,
    heading: np.ndarray,
    tilt: np.ndarray,
    follow: np.ndarray | None,
) -> np.ndarray:
    """World proxy vertices into the frames Joint2Coarse predicts them in.

    Vertex i of frame t is expressed in ``R_i = heading (heading^T root)^follow[i]``: the
    heading frame turned by ``follow[i]`` of the root's tilt. So the waistband (the largest
    follow) tilts with the pelvis, and the hem (follow 0) turns only with the heading. With
    ``follow`` None (or all zero) it is :func:`to_root_frame`, the paper's frame.

    Parameters
    ----------
    points : (T, Vc, 3) float
    origin : (T, 3) float
    heading : (T, 3, 3) float
    tilt : (T, 3) float
        :func:`tilt_rotvecs` of the frames.
    follow : (Vc,) float or None
        :func:`follow_weights`.

    Returns
    -------
    (T, Vc, 3) float64
    """
    local = to_root_frame(points, origin, heading)
    if follow is None or not np.any(follow):
        return local
    return rotate_partially(local, -np.asarray(tilt, np.float64), follow)


def from_output_frame(
    points: np.ndarray,
    origin: np.ndarray,
    heading: np.ndarray,
    tilt: np.ndarray,
    follow: np.ndarray | None,
) -> np.ndarray:
    """The inverse of :func:`to_output_frame`; same shapes."""
    if follow is not None and np.any(follow):
        points = rotate_partially(points, tilt, follow)
    return from_root_frame(points, origin, heading)


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
