"""What moves the body during a simulation: the motion resampled at every solver step.

The body starts in the rest pose (the garment's rest pose), blends to the clip's first frame
over ``transition_s`` (smoothstep in time, slerp per joint), holds it for ``settle_s``, then
plays the clip; between frames the local joint rotations are slerped and the root is
interpolated linearly, so the colliders and the pinned waistband follow the skeleton at every
substep, not only at frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InputError
from core.numeric import smoothstep
from core.skeleton import Skeleton, forward_kinematics, skinning_transforms


@dataclass(frozen=True)
class BodyDrive:
    """Body poses at every solver step boundary.

    Attributes
    ----------
    transforms : (S + 1, J, 4, 4) float32
        Skinning transforms at the start of step 0 and at the end of every step.
    dt : float
        Seconds per solver step.
    steps_per_frame : int
        Solver steps per clip frame.
    preroll_steps : int
        Steps before clip frame 0 (transition and settle); the pose after them is frame 0.
    num_frames : int
        Clip frames T; ``S = preroll_steps + (T - 1) * steps_per_frame``.
    """

    transforms: np.ndarray
    dt: float
    steps_per_frame: int
    preroll_steps: int
    num_frames: int

    @property
    def num_steps(self) -> int:
        return len(self.transforms) - 1

    def frame_step(self, frame: int) -> int:
        """Index (into ``transforms``) of the pose that is clip frame ``frame``."""
        return self.preroll_steps + frame * self.steps_per_frame


def _slerp(r0: np.ndarray, r1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per-element slerp of rotation matrices: r0, r1 (..., 3, 3), w (...) -> (..., 3, 3)."""
    from scipy.spatial.transform import Rotation

    shape = r0.shape[:-2]
    a = Rotation.from_matrix(r0.reshape(-1, 3, 3))
    b = Rotation.from_matrix(r1.reshape(-1, 3, 3))
    rel = (a.inv() * b).as_rotvec() * np.broadcast_to(w, shape).reshape(-1, 1)
    return (a * Rotation.from_rotvec(rel)).as_matrix().reshape(shape + (3, 3))


def body_drive(
    skeleton: Skeleton,
    rotations: np.ndarray,
    root_positions: np.ndarray,
    fps: float,
    steps_per_frame: int,
    transition_s: float,
    settle_s: float,
) -> BodyDrive:
    """Resample a clip (with its lead-in from the rest pose) at every solver step.

    Parameters
    ----------
    skeleton : the body's rest skeleton (J joints); the clip's rotations are applied to it
    rotations : (T, J, 3, 3) float, local joint rotations of the clip
    root_positions : (T, 3) float, root positions of the clip
    fps : clip frame rate
    steps_per_frame : solver steps per clip frame (>= 1)
    transition_s, settle_s : seconds of rest-to-frame-0 blend, then of holding frame 0
    """
    rotations = np.asarray(rotations, np.float64)
    root_positions = np.asarray(root_positions, np.float64)
    t, j = rotations.shape[:2]
    if t < 1 or rotations.shape != (t, skeleton.num_joints, 3, 3):
        raise InputError(
            f"motion rotations must be (T, {skeleton.num_joints}, 3, 3), got {rotations.shape}"
        )
    n = int(steps_per_frame)
    dt = 1.0 / (fps * n)
    n_blend = round(transition_s / dt)
    n_hold = round(settle_s / dt)
    # Lead-in: rest -> frame 0 (smoothstep), then hold.
    rest_root = skeleton.rest_positions()[0].astype(np.float64)
    u = np.arange(0, n_blend + 1) / max(n_blend, 1) if n_blend else np.ones(1)
    w = smoothstep(u)
    eye = np.broadcast_to(np.eye(3), (len(w), j, 3, 3))
    lead_rot = _slerp(eye, np.broadcast_to(rotations[0], (len(w), j, 3, 3)), w[:, None])
    lead_root = rest_root + w[:, None] * (root_positions[0] - rest_root)
    if not n_blend:  # no transition: start at frame 0
        lead_rot, lead_root = rotations[:1], root_positions[:1]
    hold_rot = np.broadcast_to(rotations[0], (n_hold, j, 3, 3))
    hold_root = np.broadcast_to(root_positions[0], (n_hold, 3))
    # Clip: between frames f and f+1, steps at fractions k/n, k = 1..n.
    if t > 1:
        frac = np.arange(1, n + 1) / n
        r0 = np.repeat(rotations[:-1], n, axis=0)
        r1 = np.repeat(rotations[1:], n, axis=0)
        wf = np.tile(frac, t - 1)
        clip_rot = _slerp(r0, r1, wf[:, None])
        p0 = np.repeat(root_positions[:-1], n, axis=0)
        p1 = np.repeat(root_positions[1:], n, axis=0)
        clip_root = p0 + wf[:, None] * (p1 - p0)
    else:
        clip_rot = np.zeros((0, j, 3, 3))
        clip_root = np.zeros((0, 3))
    all_rot = np.concatenate([lead_rot, hold_rot, clip_rot])
    all_root = np.concatenate([lead_root, hold_root, clip_root])
    pos, grot = forward_kinematics(skeleton, all_rot, all_root)
    transforms = skinning_transforms(skeleton, pos, grot)
    preroll = len(lead_rot) - 1 + n_hold
    return BodyDrive(transforms, dt, n, preroll, t)
