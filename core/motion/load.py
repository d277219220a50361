"""Loading a BVH, glTF or DeepMimic file as a normalised :class:`Motion`: metres, Y up, mapped,
resampled.

A ``.gltf``/``.glb`` file's skeleton animation (:mod:`core.motion.gltf`) is metres and Y up by
the glTF specification, and so is a DeepMimic motion (``.txt``/``.json``,
:mod:`core.motion.deepmimic`) by its own: no unit or up-axis detection for either, unless
``scale``/``up_axis`` say otherwise. The rest of this docstring is about BVH files, which carry
neither.

Units and up axis come from the rest skeleton (the first frame when the rest pose is not
upright): the up axis is the one the head sits above the feet along (``y`` or ``z``), and the
unit is the known one (metres, centimetres, millimetres, inches, the CMU unit) that makes the
standing height a plausible adult's (1.0-2.3 m), nearest 1.70 m; with none plausible the scale
makes the person 1.70 m and ``meta["unit"]`` says ``estimated``. A ``scale`` argument (metres per
file unit) always wins (``unit`` then says ``user``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from core.constants import CM_M, CMU_UNIT_M, INCH_M
from core.errors import InputError
from core.motion.bvh import clip_to_motion, read_bvh
from core.motion.deepmimic import DEEPMIMIC_SUFFIXES, read_deepmimic
from core.motion.gltf import GLTF_SUFFIXES, gltf_to_motion
from core.motion.mapping import JointMapping, canonical_positions, map_skeleton, read_mapping_file
from core.motion.motion import Motion
from core.motion.retarget import source_floor
from core.skeleton import Skeleton, forward_kinematics

#: Known units, metres per file unit.
KNOWN_UNITS: dict[str, float] = {
    "m": 1.0, "cm": CM_M, "mm": 0.001, "inch": INCH_M, "cmu": CMU_UNIT_M,
}  # fmt: skip
#: Standing heights (metres) a known unit must give to be believed.
PLAUSIBLE_HEIGHT_M = (1.0, 2.3)
#: Height assumed when no known unit gives a plausible one.
ASSUMED_HEIGHT_M = 1.70
#: Change of basis from a Z-up right-handed frame to Y up: (x, y, z) -> (x, z, -y).
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
_AXES = {"y": 1, "z": 2}
#: Motion files :func:`load_motion` reads (any other name is read as BVH).
MOTION_FILE_SUFFIXES: tuple[str, ...] = (".bvh", *GLTF_SUFFIXES, *DEEPMIMIC_SUFFIXES)


def load_motion(
    path: str | os.PathLike,
    *,
    fps: float | None = None,
    scale: float | None = None,
    mapping: str | os.PathLike | dict[str, str] | None = None,
    up_axis: str | None = None,
    repeat: int = 1,
) -> Motion:
    """Read a BVH, a skinned glTF/GLB or a DeepMimic file as a Motion in metres, Y up,
    right-handed.

    Parameters
    ----------
    path : the BVH file, a ``.gltf``/``.glb`` with a skin and an animation, or a DeepMimic
        motion (``.txt``/``.json``)
    fps : resample to this frame rate (same duration), optional
    scale : metres per file unit, overriding the detected unit
    mapping : a mapping file path or ``{canonical: source}`` dict for rigs the matcher misses
    up_axis : ``"y"`` or ``"z"``, overriding the detected up axis
    repeat : play a looping DeepMimic clip (``"Loop": "wrap"``) this many times
        (:func:`~core.motion.deepmimic.read_deepmimic`); other files accept only 1

    Returns
    -------
    Motion on the source skeleton (its joint names), with ``meta``: ``up_axis``, ``unit``,
    ``unit_scale``, ``source_joints``, ``rig``, ``mapping`` ({canonical: source} for Hips + 19),
    ``joint_mapping`` (the :class:`JointMapping`), ``standing_height_m``, ``source_fps``,
    ``wrapper_joints`` (joints above the skeleton folded into its root, see
    :func:`~core.motion.bvh.clip_to_motion`).

    Raises
    ------
    InputError
        Bad file, unknown rig, bad mapping file, bad ``scale``/``fps``/``up_axis``.
    """
    path = os.fspath(path)
    if scale is not None and not (math.isfinite(scale) and scale > 0):
        raise InputError(f"scale must be a positive number of metres per unit, got {scale}", path)
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be positive, got {fps}", path)
    if up_axis is not None and up_axis not in _AXES:
        raise InputError(f"up axis must be 'y' or 'z', got {up_axis!r}", path)
    user, mapping_path = None, None
    if isinstance(mapping, dict):
        user = mapping
    elif mapping is not None:
        mapping_path = os.fspath(mapping)
        user = read_mapping_file(mapping_path)

    suffix = Path(path).suffix.lower()
    is_gltf = suffix in GLTF_SUFFIXES
    is_deepmimic = suffix in DEEPMIMIC_SUFFIXES
    metric = is_gltf or is_deepmimic  # metres and Y up by their formats
    if repeat != 1 and not is_deepmimic:
        raise InputError(
            f"repeat={repeat!r}: only a looping DeepMimic clip (.txt/.json) is repeated", path
        )
    if is_gltf:  # sampled at fps directly: no second resampling below
        raw = gltf_to_motion(path, fps=fps)
    elif is_deepmimic:
        raw = read_deepmimic(path, repeat=repeat)
    else:
        raw = clip_to_motion(read_bvh(path), name=Path(path).stem, path=path)
    joint_mapping = map_skeleton(raw.skeleton, user, path=path, mapping_path=mapping_path)
    detected_up = "y" if metric else detect_up_axis(raw, joint_mapping)
    up = up_axis or detected_up
    motion = z_up_to_y_up(raw) if up == "z" else raw
    height_units = standing_height(motion, joint_mapping)
    if not height_units > 0 and not metric:
        raise InputError("cannot measure the standing height: head is not above the feet", path)
    if scale is not None:
        unit = next((n for n, s in KNOWN_UNITS.items() if math.isclose(s, scale)), "user")
        unit_scale = float(scale)
    elif metric:
        unit, unit_scale = "m", 1.0
    else:
        unit, unit_scale = detect_unit(height_units)
    motion = scale_motion(motion, unit_scale)
    meta = dict(raw.meta)
    if "varying_translations" in meta:
        meta["varying_translations"] = {
            k: v * unit_scale for k, v in meta["varying_translations"].items()
        }
    meta.update(
        up_axis=up,
        detected_up_axis=detected_up,
        unit=unit,
        unit_scale=unit_scale,
        rig=joint_mapping.rig,
        mapping=joint_mapping.as_dict(),
        joint_mapping=joint_mapping,
        standing_height_m=float(height_units * unit_scale),
        source_fps=(raw.meta.get("keyframe_fps") or raw.fps) if is_gltf else raw.fps,
    )
    motion = Motion(
        skeleton=motion.skeleton,
        rotations=motion.rotations,
        root_positions=motion.root_positions,
        fps=motion.fps,
        name=raw.name,
        meta=meta,
    )
    if fps is not None and not math.isclose(fps, motion.fps):
        motion = resample(motion, fps)
    return motion


def detect_unit(height_units: float) -> tuple[str, float]:
    """``(unit name, metres per unit)`` for a standing height measured in file units."""
    best = None
    lo, hi = PLAUSIBLE_HEIGHT_M
    for name, s in KNOWN_UNITS.items():
        h = height_units * s
        if lo <= h <= hi:
            miss = abs(math.log(h / ASSUMED_HEIGHT_M))
            if best is None or miss < best[0]:
                best = (miss, name, s)
    if best is not None:
        return best[1], best[2]
    return "estimated", ASSUMED_HEIGHT_M / height_units


def _extremes(
    skeleton: Skeleton,
    positions: np.ndarray,
    global_rotations: np.ndarray | None,
    mapping: JointMapping,
) -> tuple[np.ndarray, np.ndarray]:
    """Top-of-head and lowest foot candidates of one pose: ((H, 3), (F, 3)) float64.

    positions : (J, 3) float; global_rotations : (J, 3, 3) float or None (rest pose).
    Head: the head joint, its descendants and their end sites; when the head has none of these
    (a bare head joint), the top is extrapolated twice the neck-to-head distance above it.
    Feet: both foot joints, their descendants (toes) and end sites.
    """
    names = skeleton.names
    pos = np.asarray(positions, np.float64)
    ends = skeleton.end_sites.astype(np.float64)
    if global_rotations is not None:
        ends = np.einsum("jab,jb->ja", np.asarray(global_rotations, np.float64), ends)
    has_end = np.abs(skeleton.end_sites).sum(axis=1) > 0

    def subtree(root: int) -> list[int]:
        out = [root]
        for k in range(root + 1, len(names)):
            if skeleton.parents[k] in out:
                out.append(k)
        return out

    def points(root: int) -> np.ndarray:
        ks = subtree(root)
        pts = [pos[ks]] + [pos[k] + ends[k] for k in ks if has_end[k]]
        return np.vstack(pts)

    head = names.index(mapping.primary("Head"))
    head_pts = points(head)
    if len(head_pts) == 1:
        neck = names.index(mapping.primary("Neck"))
        head_pts = np.vstack([head_pts, pos[head] + 2.0 * (pos[head] - pos[neck])])
    feet = [points(names.index(mapping.primary(f"{s}Foot"))) for s in ("Left", "Right")]
    return head_pts, np.vstack(feet)


def _upright(head: np.ndarray, feet: np.ndarray) -> np.ndarray:
    """Vector from the feet's centre to the head's centre: (3,) float64."""
    return head.mean(axis=0) - feet.mean(axis=0)


def detect_up_axis(motion: Motion, mapping: JointMapping) -> str:
    """``"y"`` or ``"z"``: the axis the head is above the feet along, in the rest pose, or in the
    first frame when the rest pose is not upright (head-to-feet not mostly along one axis)."""
    sk = motion.skeleton
    v = _upright(*_extremes(sk, sk.rest_positions(), None, mapping))
    n = np.linalg.norm(v)
    if not (n > 0 and np.abs(v).max() >= 0.7 * n):
        pos, rot = forward_kinematics(sk, motion.rotations[:1], motion.root_positions[:1])
        v = _upright(*_extremes(sk, pos[0], rot[0], mapping))
    return "z" if v[2] > v[1] else "y"


def standing_height(motion: Motion, mapping: JointMapping | None = None) -> float:
    """Top of the head to the floor along Y, in the motion's units.

    The taller of the rest pose and the first frame, each counted only when upright (head above
    the feet, mostly along Y): a rest pose with splayed legs (CMU's) or a crouching first frame
    only ever makes a person look shorter. In the first frame the floor is the capture's ground
    plane (y = 0) when it lies just below where the feet touch down over the clip (within 8% of
    the height): motion capture places the toe joints a few centimetres above the sole (CMU
    01_01: 3.8 cm), so the toes alone would make every captured person look shorter.
    The motion must be Y up (every loaded motion is). Returns 0.0 when neither pose is upright.
    """
    if mapping is None:
        mapping = motion.meta.get("joint_mapping") or map_skeleton(motion.skeleton)
    sk = motion.skeleton
    frames = np.unique(
        np.linspace(0, motion.num_frames - 1, min(motion.num_frames, 200)).astype(int)
    )
    pos, rot = forward_kinematics(sk, motion.rotations[frames], motion.root_positions[frames])
    lowest = np.array([_extremes(sk, p, r, mapping)[1][:, 1].min() for p, r in zip(pos, rot)])
    floor = min(float(lowest[0]), float(np.percentile(lowest, 5)))
    head_top = float(_extremes(sk, pos[0], rot[0], mapping)[0][:, 1].max())
    if 0.0 <= floor <= 0.08 * (head_top - floor):
        floor = 0.0  # the capture's ground plane
    best = 0.0
    for p, r, ground in ((sk.rest_positions(), None, None), (pos[0], rot[0], floor)):
        head, feet = _extremes(sk, p, r, mapping)
        v = _upright(head, feet)
        h = float(head[:, 1].max() - (feet[:, 1].min() if ground is None else ground))
        if h > 0 and v[1] >= 0.7 * np.linalg.norm(v):
            best = max(best, h)
    return best


def root_travel(motion: Motion) -> tuple[float, float]:
    """``(path length, net displacement)`` of the root on the ground plane (X, Z), motion units."""
    xz = motion.root_positions[:, [0, 2]].astype(np.float64)
    path = float(np.linalg.norm(np.diff(xz, axis=0), axis=1).sum())
    return path, float(np.linalg.norm(xz[-1] - xz[0]))


def z_up_to_y_up(motion: Motion) -> Motion:
    """Re-express a Z-up right-handed motion in Y up: every point p becomes ``C @ p`` with
    ``C = Z_UP_TO_Y_UP``; offsets and end sites rotate with it and local rotations become
    ``C @ R @ C.T``, so forward kinematics gives ``C @`` the old joint positions."""
    return change_basis(motion, Z_UP_TO_Y_UP)


def change_basis(motion: Motion, c: np.ndarray) -> Motion:
    """Apply the rotation ``c`` (3, 3) to the whole motion (see :func:`z_up_to_y_up`)."""
    c = np.asarray(c, np.float64)
    sk = motion.skeleton
    skeleton = Skeleton(
        names=sk.names,
        parents=sk.parents,
        offsets=(sk.offsets.astype(np.float64) @ c.T).astype(np.float32),
        end_sites=(sk.end_sites.astype(np.float64) @ c.T).astype(np.float32),
    )
    rot = c @ motion.rotations.astype(np.float64) @ c.T
    root = motion.root_positions.astype(np.float64) @ c.T
    return Motion(
        skeleton=skeleton,
        rotations=rot.astype(np.float32),
        root_positions=root.astype(np.float32),
        fps=motion.fps,
        name=motion.name,
        meta=motion.meta,
    )


def scale_motion(motion: Motion, s: float) -> Motion:
    """Multiply every length (offsets, end sites, root path) by ``s``."""
    sk = motion.skeleton
    skeleton = Skeleton(
        names=sk.names,
        parents=sk.parents,
        offsets=(sk.offsets.astype(np.float64) * s).astype(np.float32),
        end_sites=(sk.end_sites.astype(np.float64) * s).astype(np.float32),
    )
    return Motion(
        skeleton=skeleton,
        rotations=motion.rotations,
        root_positions=(motion.root_positions.astype(np.float64) * s).astype(np.float32),
        fps=motion.fps,
        name=motion.name,
        meta=motion.meta,
    )


def resample(motion: Motion, fps: float) -> Motion:
    """Resample to ``fps`` over the same duration: ``T' = round((T - 1) * fps / fps_old) + 1``.

    Rotations are slerped per joint (scipy), the root is interpolated linearly. Frame k of the
    result is at time ``k / fps``, clamped to the last source frame.
    """
    from scipy.spatial.transform import Rotation, Slerp

    if not (math.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be positive, got {fps}")
    t_old = motion.num_frames
    t_new = int(round((t_old - 1) * fps / motion.fps)) + 1
    src_times = np.arange(t_old) / motion.fps
    times = np.minimum(np.arange(t_new) / fps, src_times[-1])
    j = motion.skeleton.num_joints
    if t_old == 1:
        rot = np.repeat(motion.rotations, t_new, axis=0)
        root = np.repeat(motion.root_positions, t_new, axis=0)
    else:
        rot = np.empty((t_new, j, 3, 3))
        for k in range(j):
            r = Rotation.from_matrix(motion.rotations[:, k].astype(np.float64))
            rot[:, k] = Slerp(src_times, r)(times).as_matrix()
        root = np.stack(
            [np.interp(times, src_times, motion.root_positions[:, a]) for a in range(3)], axis=1
        )
    meta = dict(motion.meta)
    meta["resampled_from_fps"] = motion.fps
    return Motion(
        skeleton=motion.skeleton,
        rotations=rot.astype(np.float32),
        root_positions=root.astype(np.float32),
        fps=float(fps),
        name=motion.name,
        meta=meta,
    )


def motion_info(motion: Motion) -> dict:
    """What ``dng motion info`` reports, as JSON-ready plain types (lengths in metres)."""
    mapping: JointMapping = motion.meta.get("joint_mapping") or map_skeleton(motion.skeleton)
    path_len, net = root_travel(motion)
    return {
        "name": motion.name,
        "frames": motion.num_frames,
        "fps": motion.fps,
        "duration_s": motion.duration,
        "source_joints": list(motion.skeleton.names),
        "num_source_joints": motion.skeleton.num_joints,
        "rig": mapping.rig,
        "root": mapping.source_of("Hips"),
        "joints": {c: mapping.source_of(c) for c in mapping.as_dict() if c != "Hips"},
        "up_axis": motion.meta.get("up_axis", "y"),
        "unit": motion.meta.get("unit", "m"),
        "unit_scale": motion.meta.get("unit_scale", 1.0),
        "standing_height_m": standing_height(motion, mapping),
        "floor": source_floor(canonical_positions(motion, mapping), motion.fps).summary(),
        "root_path_length_m": path_len,
        "root_displacement_m": net,
        "varying_translations_m": motion.meta.get("varying_translations", {}),
        "wrapper_joints": motion.meta.get("wrapper_joints", []),
        "deepmimic": (
            {"loop": motion.meta["loop"], "repeat": motion.meta["repeat"]}
            if "deepmimic_joints" in motion.meta
            else None
        ),
    }
