"""Synthetic Joint2Coarse data: a walking mannequin and a "skirt" whose shape follows the motion.

For tests and benchmarks, where no simulator runs. The skirt is a cone hanging from the hips,
written in the root (heading) frame of each frame; its hem lags behind the hips' velocity,
swirls against the hips' yaw rate, and bulges towards the knees, all over the last few frames,
so its shape is a smooth, deterministic function of the joint motion history.
"""

from __future__ import annotations

import numpy as np

from core.body.shape import MANNEQUIN_JOINTS, mannequin_skeleton
from core.motion.motion import Motion
from core.proxy.testing import ring_faces
from core.skeleton import rotation_about
from training.joint2coarse.descriptor import (
    canonical_joint_order,
    from_root_frame,
    heading_rotations,
    joint2coarse_inputs,
    to_root_frame,
)


def synthetic_walk(num_frames: int, seed: int, fps: float = 30.0) -> Motion:
    """A mannequin walking a wandering path with swinging legs, twisting hips and a bobbing root.

    Each seed draws its own speeds, turn rates and phases (quasi-periodic: no two stretches
    repeat exactly). Returns a :class:`Motion` on ``mannequin_skeleton()``.
    """
    rng = np.random.default_rng(seed)
    skel = mannequin_skeleton()
    t = np.arange(num_frames) / fps
    j = len(MANNEQUIN_JOINTS)
    x_axis, y_axis, z_axis = np.eye(3)
    step_f = rng.uniform(0.8, 1.1)  # strides per second
    phase = 2 * np.pi * step_f * t + rng.uniform(0, 2 * np.pi)
    turn = rng.uniform(0.2, 0.5) * np.sin(
        2 * np.pi * rng.uniform(0.05, 0.12) * t + rng.uniform(0, 6)
    )
    turn += rng.uniform(-0.2, 0.2)
    yaw = np.cumsum(turn) / fps + rng.uniform(0, 2 * np.pi)
    speed = rng.uniform(0.6, 1.4) + 0.4 * np.sin(2 * np.pi * rng.uniform(0.07, 0.15) * t)
    fwd = np.stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], -1)
    root = np.cumsum(fwd * speed[:, None], axis=0) / fps
    root[:, 1] = skel.offsets[0, 1] + 0.02 * np.cos(2 * phase)
    hip_twist = 0.25 * np.sin(phase) + 0.1 * np.sin(2.3 * phase + 1.0)
    rot = np.tile(np.eye(3), (num_frames, j, 1, 1))
    rot[:, 0] = rotation_about(y_axis, yaw + hip_twist) @ rotation_about(
        z_axis, 0.06 * np.sin(phase + 0.5)
    )
    swing = 0.5 * np.sin(phase)
    for name, sign in (("LeftUpLeg", 1.0), ("RightUpLeg", -1.0)):
        rot[:, MANNEQUIN_JOINTS.index(name)] = rotation_about(x_axis, -sign * swing)
        knee = np.maximum(0.0, sign * np.sin(phase + 0.6)) * 0.8
        rot[:, MANNEQUIN_JOINTS.index(name.replace("UpLeg", "Leg"))] = rotation_about(x_axis, knee)
    rot[:, MANNEQUIN_JOINTS.index("Spine")] = rotation_about(y_axis, -0.6 * hip_twist)
    for name, sign in (("LeftArm", 1.0), ("RightArm", -1.0)):
        rot[:, MANNEQUIN_JOINTS.index(name)] = rotation_about(x_axis, sign * 0.4 * np.sin(phase))
    return Motion(skel, rot.astype(np.float32), root.astype(np.float32), fps, f"synthetic-{seed}")


def skirt_from_joints(
    joints: np.ndarray, root_rotations: np.ndarray, rings: int = 6, around: int = 20
) -> np.ndarray:
    """The synthetic skirt's vertices for a joint clip.

    Parameters
    ----------
    joints : (T, 20, 3) float
        Root then CANONICAL_JOINTS (:func:`joint2coarse_inputs`).
    root_rotations : (T, 3, 3) float
    rings, around : int
        Vertex rings from waist to hem, and vertices per ring: ``Vc = rings * around``.

    Returns
    -------
    (T, rings * around, 3) float32 world positions.
    """
    joints = np.asarray(joints, np.float64)
    n = len(joints)
    origin = joints[:, 0]
    heading = heading_rotations(root_rotations)
    yaw = np.arctan2(heading[:, 0, 2], heading[:, 0, 0])

    def past(a: np.ndarray, lag: int) -> np.ndarray:
        return a[np.maximum(np.arange(n) - lag, 0)]

    # Hip velocity in the current root frame, smoothed over the last 6 frames (metres/frame).
    vel = np.zeros((n, 3))
    for lag, w in ((0, 0.5), (2, 0.3), (4, 0.2)):
        d = past(origin, lag) - past(origin, lag + 2)
        vel += w * np.einsum("tji,tj->ti", heading, d) / 2.0
    # Yaw rate (radians/frame), smoothed the same way.
    rate = np.zeros(n)
    for lag, w in ((0, 0.5), (2, 0.3), (4, 0.2)):
        d = past(yaw, lag) - past(yaw, lag + 2)
        rate += w * ((d + np.pi) % (2 * np.pi) - np.pi) / 2.0
    knees = to_root_frame(joints[:, [14, 17]], origin, heading)  # LeftLeg, RightLeg

    h = np.linspace(0.0, 1.0, rings)[:, None]  # 0 at the waist, 1 at the hem
    phi = np.linspace(0.0, 2 * np.pi, around, endpoint=False)[None, :]
    out = np.empty((n, rings, around, 3))
    for f in range(n):
        ang = phi - 6.0 * h**2 * rate[f]
        rho = 0.16 + 0.22 * h
        dirs = np.stack([np.sin(ang), np.zeros_like(ang), np.cos(ang)], -1)
        bulge = np.zeros_like(ang)
        for k in knees[f]:
            kd = np.array([k[0], 0.0, k[2]])
            bulge += 0.4 * np.maximum(0.0, dirs @ kd) * h
        p = dirs * (rho + bulge)[..., None]
        p[..., 1] = -0.62 * h
        p -= 3.0 * (h**2)[..., None] * np.array([vel[f, 0], 0.0, vel[f, 2]])
        out[f] = p
    local = out.reshape(n, rings * around, 3)
    return from_root_frame(local, origin, heading).astype(np.float32)


def rest_skirt(rings: int = 6, around: int = 20) -> np.ndarray:
    """(rings * around, 3) float32: :func:`skirt_from_joints` on the mannequin's rest pose
    (world), the rest proxy of a rig (``body_rig``) for the synthetic skirt."""
    skel = mannequin_skeleton()
    rest = canonical_joint_order(skel.rest_positions()[None], skel.names)
    return skirt_from_joints(rest, np.eye(3)[None], rings, around)[0]


def skirt_faces(rings: int = 6, around: int = 20) -> np.ndarray:
    """Triangles of :func:`skirt_from_joints`'s vertex grid (vertex ``r * around + k``: ring r,
    angle k, rings going down): :func:`~core.proxy.testing.ring_faces`, outward."""
    return ring_faces(rings, around)


def synthetic_clip(num_frames: int, seed: int, rings: int = 6, around: int = 20):
    """``(joints, root_rotations, skirt)`` of :func:`synthetic_walk` and its skirt."""
    joints, root_rot = joint2coarse_inputs(synthetic_walk(num_frames, seed))
    return joints, root_rot, skirt_from_joints(joints, root_rot, rings, around)
