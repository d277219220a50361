"""Variations of a clip for training data: played faster or slower, with larger or smaller joint
rotations, turned to another heading.

Pure functions of a :class:`~core.motion.motion.Motion`; the skeleton is unchanged, so a clip on
the mannequin stays on the mannequin.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from core.errors import InputError
from core.motion.load import resample
from core.motion.motion import Motion


def source_frames(frames: int, speed: float) -> int:
    """Frames of a clip that, played ``speed`` times faster, give ``frames`` frames."""
    return int(math.ceil((frames - 1) * speed - 1e-9)) + 1


def vary_motion(
    motion: Motion,
    speed: float = 1.0,
    amplitude: float = 1.0,
    heading_deg: float = 0.0,
    turn_deg_s: float = 0.0,
) -> Motion:
    """The clip played ``speed`` times faster, its joint rotations scaled, turned about +Y.

    Parameters
    ----------
    motion : Motion, T frames at ``fps``
    speed : float > 0
        Time scale: the result covers ``speed`` times the clip's time per second, at the same
        fps (``(T - 1) / speed + 1`` frames, rounded; slerped in between).
    amplitude : float >= 0
        Every non-root joint's local rotation angle is multiplied by this (about its own axis):
        1 keeps the clip, below 1 calms it towards the rest pose, above 1 exaggerates it. The
        root's rotation and path are kept.
    heading_deg : float
        The whole clip (root rotation and root path) turned about the vertical axis through the
        origin by this many degrees.
    turn_deg_s : float
        The body also turns at this many degrees per second about the vertical, after the speed
        change: the root's rotation turns, and so does each frame's step of the root, so the
        clip's own speed is kept (an idle becomes a pirouette, a walk curls into a circle).

    Returns
    -------
    Motion on the same skeleton, at the same fps.
    """
    for name, v, ok in (
        ("speed", speed, speed > 0),
        ("amplitude", amplitude, amplitude >= 0),
        ("heading_deg", heading_deg, True),
        ("turn_deg_s", turn_deg_s, True),
    ):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and ok):
            raise InputError(f"motion variation {name}={v!r} is out of range", motion.name or None)
    out = motion
    if speed != 1.0:
        out = resample(replace(out, fps=out.fps * speed), motion.fps)
    rotations = np.array(out.rotations, np.float32)
    roots = np.array(out.root_positions, np.float32)
    if amplitude != 1.0:
        t, j = rotations.shape[:2]
        rv = Rotation.from_matrix(rotations[:, 1:].reshape(-1, 3, 3)).as_rotvec() * amplitude
        rotations[:, 1:] = Rotation.from_rotvec(rv).as_matrix().reshape(t, j - 1, 3, 3)
    if heading_deg != 0.0:
        turn = Rotation.from_euler("y", heading_deg, degrees=True).as_matrix().astype(np.float32)
        rotations[:, 0] = turn @ rotations[:, 0]
        roots = roots @ turn.T
    if turn_deg_s != 0.0:
        angles = turn_deg_s * np.arange(len(roots)) / out.fps
        turn = Rotation.from_euler("y", angles[:, None], degrees=True).as_matrix()
        turn = turn.astype(np.float32)
        rotations[:, 0] = turn @ rotations[:, 0]
        # Each frame's step turns with the body: the clip's own speed is kept, a walk curls
        # into a circle, an idle spins in place.
        steps = np.einsum("tij,tj->ti", turn[1:], np.diff(roots, axis=0))
        roots = np.concatenate([roots[:1], roots[0] + np.cumsum(steps, axis=0)])
    return replace(out, rotations=rotations, root_positions=roots.astype(np.float32))
