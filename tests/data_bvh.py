"""BVH files "from other tools", made by converting a CMU clip, for the motion import tests.

Each conversion keeps the CMU clip's motion exactly (same world joint positions up to units and
axes) while changing what the importer has to cope with: joint names and hierarchy conventions,
rotation order, 6 channels on every joint, units, Z up, CRLF line ends and indentation.

- ``biped``: 3ds Max Biped names (``Bip001`` root above ``Bip001 Pelvis``, ``Bip001 L Thigh``...),
  Z up, 6 channels on every joint, an arbitrary unit (``BIPED_UNIT_M`` metres), CRLF.
- ``mixamo``: ``mixamorig:`` names, centimetres, Y up, ``HeadTop_End`` joint, spaces.
- ``rigify``: LAFAN/Rigify-style ``DEF-`` names with Rigify's numbered spine
  (``DEF-spine`` = hips ... ``DEF-spine.006`` = head), metres, Y up, XYZ order, tabs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from core.constants import CM_M, CMU_UNIT_M
from core.motion.bvh import clip_to_motion, matrix_to_euler, read_bvh

#: Metres per file unit of the Biped conversion: no known unit, so the importer must estimate.
BIPED_UNIT_M = 0.137

_MIXAMO = {
    "Hips": "Hips", "LeftUpLeg": "LeftUpLeg", "LeftLeg": "LeftLeg", "LeftFoot": "LeftFoot",
    "LeftToeBase": "LeftToeBase", "LowerBack": "Spine", "Spine": "Spine1", "Spine1": "Spine2",
    "Neck": "Neck", "Neck1": "Neck1", "Head": "Head", "LeftShoulder": "LeftShoulder",
    "LeftArm": "LeftArm", "LeftForeArm": "LeftForeArm", "LeftHand": "LeftHand",
    "LeftFingerBase": "LeftHandIndex1", "LFingers": "LeftHandIndex2", "LThumb": "LeftHandThumb1",
}  # fmt: skip
_BIPED = {
    "Hips": "Pelvis", "LeftUpLeg": "L Thigh", "LeftLeg": "L Calf", "LeftFoot": "L Foot",
    "LeftToeBase": "L Toe0", "LowerBack": "Spine", "Spine": "Spine1", "Spine1": "Spine2",
    "Neck": "Neck", "Neck1": "Neck1", "Head": "Head", "LeftShoulder": "L Clavicle",
    "LeftArm": "L UpperArm", "LeftForeArm": "L Forearm", "LeftHand": "L Hand",
    "LeftFingerBase": "L Finger0", "LFingers": "L Finger01", "LThumb": "L Finger1",
}  # fmt: skip
_RIGIFY = {
    "Hips": "spine", "LeftUpLeg": "thigh.L", "LeftLeg": "shin.L", "LeftFoot": "foot.L",
    "LeftToeBase": "toe.L", "LowerBack": "spine.001", "Spine": "spine.002",
    "Spine1": "spine.003", "Neck": "spine.004", "Neck1": "spine.005", "Head": "spine.006",
    "LeftShoulder": "shoulder.L", "LeftArm": "upper_arm.L", "LeftForeArm": "forearm.L",
    "LeftHand": "hand.L", "LeftFingerBase": "f_index.01.L", "LFingers": "f_index.02.L",
    "LThumb": "thumb.01.L",
}  # fmt: skip


def _rename(cmu: str, style: str) -> str:
    table = {"mixamo": _MIXAMO, "biped": _BIPED, "rigify": _RIGIFY}[style]
    mirrored = {
        "RightUpLeg": "LeftUpLeg", "RightLeg": "LeftLeg", "RightFoot": "LeftFoot",
        "RightToeBase": "LeftToeBase", "RightShoulder": "LeftShoulder", "RightArm": "LeftArm",
        "RightForeArm": "LeftForeArm", "RightHand": "LeftHand",
        "RightFingerBase": "LeftFingerBase", "RFingers": "LFingers", "RThumb": "LThumb",
    }  # fmt: skip
    right = cmu in mirrored
    name = table[mirrored.get(cmu, cmu)]
    if right:
        name = (
            name.replace("Left", "Right").replace("L ", "R ").replace(".L", ".R")
            if style != "biped"
            else name.replace("L ", "R ", 1)
        )
    prefix = {"mixamo": "mixamorig:", "biped": "Bip001 ", "rigify": "DEF-"}[style]
    return prefix + name


def write_raw_bvh(
    path: Path,
    names: list[str],
    parents: list[int],
    offsets: np.ndarray,
    end_sites: dict[int, np.ndarray],
    channels: list[list[str]],
    values: np.ndarray,
    frame_time: float,
    newline: str = "\n",
    indent: str = "\t",
) -> None:
    """Write a BVH file exactly as given (an "other tool"'s writer, not the project's).

    offsets (J, 3); end_sites {joint: (3,)}; channels per joint; values (T, C) float.
    """
    lines = ["HIERARCHY"]
    children = {k: [c for c, p in enumerate(parents) if p == k] for k in range(len(names))}

    def vec(v) -> str:
        return " ".join(f"{float(x):.6f}" for x in v)

    def emit(k: int, d: int) -> None:
        pad = indent * d
        lines.append(f"{pad}{'ROOT' if k == 0 else 'JOINT'} {names[k]}")
        lines.append(pad + "{")
        lines.append(f"{pad}{indent}OFFSET {vec(offsets[k])}")
        lines.append(f"{pad}{indent}CHANNELS {len(channels[k])} {' '.join(channels[k])}")
        for c in children[k]:
            emit(c, d + 1)
        if k in end_sites:
            lines.extend([f"{pad}{indent}End Site", pad + indent + "{"])
            lines.extend([f"{pad}{indent * 2}OFFSET {vec(end_sites[k])}", pad + indent + "}"])
        lines.append(pad + "}")

    emit(0, 0)
    lines += ["MOTION", f"Frames: {len(values)}", f"Frame Time: {frame_time:.7f}"]
    lines += [" ".join(f"{x:.6f}" for x in row) for row in values]
    path.write_bytes((newline.join(lines) + newline).encode("ascii"))


def cmu_as(style: str, src: Path, out: Path, frames: slice = slice(0, 240)) -> dict:
    """Convert the CMU clip ``src`` to ``style`` (``biped``, ``mixamo``, ``rigify``) at ``out``.

    Returns ``{"unit_m": metres per unit of the new file, "up": "y" or "z",
    "cmu_to_new": {cmu joint: new joint}, "frames": count}``.
    """
    clip = read_bvh(src)
    motion = clip_to_motion(clip)
    sk = motion.skeleton
    rot = motion.rotations[frames].astype(np.float64)
    root = motion.root_positions[frames].astype(np.float64)
    offsets = sk.offsets.astype(np.float64)
    ends = sk.end_sites.astype(np.float64)
    has_end = clip.has_end_site
    # Joints that never rotate and sit on their parent (CMU's LHipJoint) carry no information.
    keep = [
        k
        for k in range(sk.num_joints)
        if k == 0 or np.linalg.norm(offsets[k]) > 0 or np.abs(rot[:, k] - np.eye(3)).max() > 1e-6
    ]
    new_parent = {}
    for k in keep[1:]:
        p = int(sk.parents[k])
        while p not in keep:  # only identity-rotation, zero-offset joints are skipped
            p = int(sk.parents[p])
        new_parent[k] = p

    unit_m = {"biped": BIPED_UNIT_M, "mixamo": CM_M, "rigify": 1.0}[style]
    s = CMU_UNIT_M / unit_m
    up = "z" if style == "biped" else "y"
    c = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]) if up == "z" else np.eye(3)  # Y up -> Z up
    order = {"biped": "ZXY", "mixamo": "ZXY", "rigify": "XYZ"}[style]
    rot_ch = [f"{a}rotation" for a in order]
    pos_ch = ["Xposition", "Yposition", "Zposition"]

    names: list[str] = []
    parents: list[int] = []
    offs: list[np.ndarray] = []
    local: list[np.ndarray] = []  # (T, 3, 3) per new joint
    chans: list[list[str]] = []
    end_sites: dict[int, np.ndarray] = {}
    index = {}
    frames_n = len(rot)
    eye = np.broadcast_to(np.eye(3), (frames_n, 3, 3))
    if style == "biped":
        names.append("Bip001")
        parents.append(-1)
        offs.append(c @ root[0] * s)
        local.append(eye)
        chans.append(pos_ch + rot_ch)
    for k in keep:
        index[k] = len(names)
        names.append(_rename(sk.names[k], style))
        if k == 0:
            parents.append(0 if style == "biped" else -1)
            offs.append(np.zeros(3) if style == "biped" else c @ root[0] * s)
        else:
            parents.append(index[new_parent[k]])
            offs.append(c @ offsets[k] * s)
        local.append(c @ rot[:, k] @ c.T)
        chans.append(pos_ch + rot_ch if (style == "biped" or k == 0) else rot_ch)
        if has_end[k]:
            if style == "mixamo" and sk.names[k] == "Head":
                names.append("mixamorig:HeadTop_End")
                parents.append(index[k])
                offs.append(c @ ends[k] * s)
                local.append(eye)
                chans.append(rot_ch)
                end_sites[len(names) - 1] = np.zeros(3)
            else:
                end_sites[index[k]] = c @ ends[k] * s
    root_new = root @ c.T * s
    cols = []
    for j, ch in enumerate(chans):
        if ch[:3] == pos_ch:
            cols.append(root_new if j == 0 else np.broadcast_to(offs[j], (frames_n, 3)))
        cols.append(matrix_to_euler(local[j], order))
    values = np.concatenate(cols, axis=1)
    write_raw_bvh(
        out,
        names,
        parents,
        np.array(offs),
        end_sites,
        chans,
        values,
        clip.frame_time,
        newline="\r\n" if style == "biped" else "\n",
        indent={"biped": "\t", "mixamo": "  ", "rigify": "\t"}[style],
    )
    return {
        "unit_m": unit_m,
        "up": up,
        "cmu_to_new": {sk.names[k]: names[index[k]] for k in keep},
        "frames": frames_n,
    }


def tiny_bvh_text(frames: int = 3, newline: str = "\n") -> str:
    """A small valid BVH (a 6-joint stick figure with End Sites, centimetres): the base the
    bad-input tests break in one place each."""
    lines = [
        "HIERARCHY",
        "ROOT Hips",
        "{",
        "\tOFFSET 0 90 0",
        "\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
        "\tJOINT Spine",
        "\t{",
        "\t\tOFFSET 0 20 0",
        "\t\tCHANNELS 3 Zrotation Xrotation Yrotation",
        "\t\tEnd Site",
        "\t\t{",
        "\t\t\tOFFSET 0 60 0",
        "\t\t}",
        "\t}",
        "}",
        "MOTION",
        f"Frames: {frames}",
        "Frame Time: 0.033333",
    ]
    for t in range(frames):
        lines.append(f"{t * 1.0} 90 0 {t * 2.0} 0 0 0 {t * 3.0} 0")
    return newline.join(lines) + newline
