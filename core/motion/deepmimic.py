"""Reading a DeepMimic motion file (the humanoid's keyframes, JSON) as a :class:`Motion`.

DeepMimic (Peng et al. 2018) stores motion capture retargeted onto its own 15-link humanoid as
JSON: ``{"Loop": "wrap" | "none", "Frames": [[...], ...]}``, one row of 44 numbers a keyframe::

    duration (s), root position (3), root rotation (4),
    chest (4), neck (4),
    right hip (4), right knee (1), right ankle (4), right shoulder (4), right elbow (1),
    left hip (4), left knee (1), left ankle (4), left shoulder (4), left elbow (1)

Rotations are unit quaternions written ``w, x, y, z``, local to the parent link (the root's in
the world); knees and elbows are hinges, an angle in radians about the joint's local z axis.
Positions are metres, Y up; the humanoid faces +X with its right side towards +Z.

The humanoid's rest pose (every rotation the identity: upright, arms hanging) is the
``humanoid.urdf`` that pybullet ships for its DeepMimic environment, at the scale that
environment loads it (``globalScaling=0.25``): :data:`DEEPMIMIC_JOINTS`. Its one-sphere head
becomes a ``Head`` joint halfway from the neck joint to the sphere's centre, with an end site at
the top of the sphere, so the head has a joint the canonical rig can map. Joints are named as
the canonical rig names them, so the name matcher (:mod:`core.motion.mapping`) reads the rig by
itself; ``meta["deepmimic_joints"]`` gives each one's DeepMimic name.

A clip whose ``Loop`` is ``wrap`` ends on its first pose moved along; ``repeat`` plays it that
many times, each repetition continuing from where the previous one ended (its last keyframe is
the next one's first, so it is kept once), as DeepMimic loops it: moved on by the root's
horizontal travel over one cycle and turned by the root's change of heading over it.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from core.errors import InputError
from core.fileio import read_input_bytes
from core.motion.gltf import sample_channel
from core.motion.motion import Motion
from core.skeleton import Skeleton, rotation_about

#: File names read as DeepMimic motion (their content must be its JSON).
DEEPMIMIC_SUFFIXES: tuple[str, ...] = (".txt", ".json")
#: Numbers in one keyframe.
FRAME_SIZE = 44
#: Largest relative spread of the keyframe durations read as one frame rate (beyond it the
#: keyframes are resampled at the median's rate).
_DURATION_SPREAD = 0.01
#: A rate within this fraction of a whole number of frames per second is that number (DeepMimic
#: writes 1/30 s as 0.033332).
_RATE_SNAP = 1e-4
_Y, _Z = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])

#: (name, DeepMimic name, parent name, rest offset from the parent (m), end site (m) or None),
#: parents first. From pybullet's ``humanoid/humanoid.urdf`` (its joint origins x 0.25; the
#: foot's end site is its box's toe at the sole, the hand's the wrist sphere's bottom).
DEEPMIMIC_JOINTS: tuple[tuple[str, str, str | None, tuple, tuple | None], ...] = (
    ("Hips", "root", None, (0.0, 0.0, 0.0), None),
    ("Chest", "chest", "Hips", (0.0, 0.236151, 0.0), None),
    ("Neck", "neck", "Chest", (0.0, 0.223894, 0.0), None),
    ("Head", "neck (the head sphere)", "Neck", (0.0, 0.0875, 0.0), (0.0, 0.19, 0.0)),
    ("RightUpLeg", "right_hip", "Hips", (0.0, 0.0, 0.084887), None),
    ("RightLeg", "right_knee", "RightUpLeg", (0.0, -0.421546, 0.0), None),
    ("RightFoot", "right_ankle", "RightLeg", (0.0, -0.40987, 0.0), (0.1335, -0.05, 0.0)),
    ("RightArm", "right_shoulder", "Chest", (-0.02405, 0.2435, 0.18311), None),
    ("RightForeArm", "right_elbow", "RightArm", (0.0, -0.274788, 0.0), None),
    ("RightHand", "right_wrist", "RightForeArm", (0.0, -0.258947, 0.0), (0.0, -0.04, 0.0)),
    ("LeftUpLeg", "left_hip", "Hips", (0.0, 0.0, -0.084887), None),
    ("LeftLeg", "left_knee", "LeftUpLeg", (0.0, -0.421546, 0.0), None),
    ("LeftFoot", "left_ankle", "LeftLeg", (0.0, -0.40987, 0.0), (0.1335, -0.05, 0.0)),
    ("LeftArm", "left_shoulder", "Chest", (-0.02405, 0.2435, -0.18311), None),
    ("LeftForeArm", "left_elbow", "LeftArm", (0.0, -0.274788, 0.0), None),
    ("LeftHand", "left_wrist", "LeftForeArm", (0.0, -0.258947, 0.0), (0.0, -0.04, 0.0)),
)  # fmt: skip
#: Where each rotated joint's values start in a keyframe, and whether it is a hinge (1 value).
_COLUMNS: dict[str, tuple[int, bool]] = {
    "Hips": (4, False), "Chest": (8, False), "Neck": (12, False),
    "RightUpLeg": (16, False), "RightLeg": (20, True), "RightFoot": (21, False),
    "RightArm": (25, False), "RightForeArm": (29, True),
    "LeftUpLeg": (30, False), "LeftLeg": (34, True), "LeftFoot": (35, False),
    "LeftArm": (39, False), "LeftForeArm": (43, True),
}  # fmt: skip


def deepmimic_skeleton() -> Skeleton:
    """The DeepMimic humanoid's rest skeleton (:data:`DEEPMIMIC_JOINTS`), metres."""
    names = tuple(j[0] for j in DEEPMIMIC_JOINTS)
    return Skeleton(
        names=names,
        parents=np.array([names.index(j[2]) if j[2] else -1 for j in DEEPMIMIC_JOINTS], np.int64),
        offsets=np.array([j[3] for j in DEEPMIMIC_JOINTS], np.float32),
        end_sites=np.array([j[4] or (0.0, 0.0, 0.0) for j in DEEPMIMIC_JOINTS], np.float32),
    )


def _yaw(rotation: np.ndarray) -> float:
    """Heading (radians about +Y) of the humanoid's forward axis (+X) under ``rotation``."""
    forward = rotation[:, 0]
    return math.atan2(-forward[2], forward[0])


def read_deepmimic(path: str | os.PathLike, repeat: int = 1) -> Motion:
    """Read a DeepMimic motion file as a Motion on :func:`deepmimic_skeleton`.

    Parameters
    ----------
    path : the JSON file (DeepMimic's ``.txt``)
    repeat : int >= 1, how many times to play a ``wrap`` clip (see the module docstring); a
        clip that does not loop accepts only 1

    Returns
    -------
    Motion in metres, Y up, at the keyframes' rate, ``(repeat * (K - 1) + 1)`` frames for a
    looping clip of K keyframes (K for one played once). Keyframes whose durations differ by
    more than 1% (some of pybullet's clips: ``roll``, ``getup_*``) are first resampled at the
    median duration's rate, as DeepMimic interpolates them. ``meta``: ``path``, ``loop``,
    ``repeat``, ``uneven_keyframes_resampled``, ``source_joints``, ``deepmimic_joints`` ({name:
    DeepMimic name}).

    Raises
    ------
    InputError
        Unreadable or not DeepMimic's JSON, a keyframe of the wrong length, non-finite values,
        a zero-length quaternion, a duration that is not positive, fewer than 2 keyframes,
        ``repeat`` below 1 or above 1 for a clip that does not loop.
    """
    path = os.fspath(path)
    raw = read_input_bytes(path, "a DeepMimic motion")
    try:
        doc = json.loads(raw.decode("utf-8-sig"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"not a DeepMimic motion (JSON with 'Frames'): {e}", path) from None
    if not isinstance(doc, dict) or not isinstance(doc.get("Frames"), list):
        raise InputError("not a DeepMimic motion: no 'Frames' list", path)
    loop = doc.get("Loop", "none")
    if loop not in ("wrap", "none"):
        raise InputError(f"unknown 'Loop' {loop!r}: DeepMimic writes 'wrap' or 'none'", path)
    if not (isinstance(repeat, int) and repeat >= 1):
        raise InputError(f"repeat must be a whole number >= 1, got {repeat!r}", path)
    if repeat > 1 and loop != "wrap":
        raise InputError(f"the clip does not loop ('Loop' is {loop!r}): it plays once", path)
    rows = doc["Frames"]
    for k, row in enumerate(rows):
        if not (isinstance(row, list) and len(row) == FRAME_SIZE):
            size = len(row) if isinstance(row, list) else type(row).__name__
            raise InputError(
                f"keyframe {k} has {size} values: the DeepMimic humanoid's have {FRAME_SIZE}", path
            )
    if len(rows) < 2:
        raise InputError(f"the clip has {len(rows)} keyframe(s): at least 2 are needed", path)
    try:
        values = np.array(rows, np.float64)
    except (TypeError, ValueError):
        raise InputError("a keyframe holds something that is not a number", path) from None
    bad = np.argwhere(~np.isfinite(values))
    if len(bad):
        raise InputError(f"keyframe {bad[0][0]} has a non-finite value (column {bad[0][1]})", path)
    durations = values[:-1, 0]
    dt = float(np.median(durations))
    if not dt > 0 or (durations <= 0).any():
        raise InputError("a keyframe duration is not positive", path)
    fps = 1.0 / dt
    if abs(fps - round(fps)) < _RATE_SNAP * fps:  # durations are written to about 6 digits
        fps = float(round(fps))
    for name, (col, hinge) in _COLUMNS.items():
        if not hinge and not (np.linalg.norm(values[:, col : col + 4], axis=1) > 1e-8).all():
            raise InputError(f"a zero-length rotation of {name} (columns {col}-{col + 3})", path)
    resampled = bool(np.abs(durations - dt).max() > _DURATION_SPREAD * dt)
    if resampled:
        values = _even(values, fps)
    skeleton = deepmimic_skeleton()
    t = len(values)
    rotations = np.broadcast_to(np.eye(3), (t, skeleton.num_joints, 3, 3)).copy()
    for name, (col, hinge) in _COLUMNS.items():
        k = skeleton.index(name)
        if hinge:
            rotations[:, k] = rotation_about(_Z, values[:, col])
            continue
        xyzw = values[:, [col + 1, col + 2, col + 3, col]]
        rotations[:, k] = Rotation.from_quat(xyzw).as_matrix()
    root = values[:, 1:4].copy()
    if repeat > 1:
        rotations, root = _play_loop(rotations, root, repeat)
    return Motion(
        skeleton=skeleton,
        rotations=rotations.astype(np.float32),
        root_positions=root.astype(np.float32),
        fps=fps,
        name=Path(path).stem,
        meta={
            "path": path,
            "loop": loop,
            "uneven_keyframes_resampled": resampled,
            "repeat": repeat,
            "source_joints": list(skeleton.names),
            "deepmimic_joints": {j[0]: j[1] for j in DEEPMIMIC_JOINTS},
        },
    )


def _even(values: np.ndarray, fps: float) -> np.ndarray:
    """Keyframes (K, 44) at uneven times (their durations, column 0) sampled at ``fps`` over the
    same span: root positions and hinge angles linearly, quaternions by slerp (what DeepMimic
    does between keyframes). Returns (T, 44), durations ``1 / fps``."""
    times = np.concatenate([[0.0], np.cumsum(values[:-1, 0])])
    at = np.arange(int(math.floor(times[-1] * fps + 1e-6)) + 1) / fps
    out = np.empty((len(at), values.shape[1]))
    out[:, 0] = 1.0 / fps
    out[:, 1:4] = sample_channel(times, values[:, 1:4], "LINEAR", at, rotation=False)
    for col, hinge in _COLUMNS.values():
        cols = slice(col, col + (1 if hinge else 4))
        out[:, cols] = sample_channel(times, values[:, cols], "LINEAR", at, rotation=not hinge)
    return out


def _play_loop(
    rotations: np.ndarray, root: np.ndarray, repeat: int
) -> tuple[np.ndarray, np.ndarray]:
    """A looping clip played ``repeat`` times: (T, J, 3, 3), (T, 3) -> (repeat (T-1) + 1, ...).

    Cycle k is the clip turned about +Y by k times the root's change of heading over the clip,
    started where cycle k - 1 ended (horizontally; heights as recorded), its first keyframe
    dropped (the previous cycle's last).
    """
    turn = _yaw(rotations[-1, 0]) - _yaw(rotations[0, 0])
    travel = root - root[0]
    travel[:, 1] = 0.0
    rot, pos = [rotations], [root]
    for k in range(1, repeat):
        h = rotation_about(_Y, k * turn)
        start = pos[-1][-1]
        p = start + travel @ h.T
        p[:, 1] = root[:, 1]
        r = rotations.copy()
        r[:, 0] = h @ rotations[:, 0]
        rot.append(r[1:])
        pos.append(p[1:])
    return np.concatenate(rot), np.concatenate(pos)
