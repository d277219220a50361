"""Rig names with exporter decorations: numeric suffixes, namespaces and paths, a wrapper root.

Every decorated file is written from an undecorated one with the same channel values (same
writer, same digits), so the two must give the same world joint positions; a wrapper root with an
offset or a rotation must move them by exactly that transform. Sources: CMU 01_01 (Debian's
assimp-testmodels), its 3ds Max Biped, Mixamo and Rigify conversions (``tests/data_bvh.py``) and a
procedural clip on the mannequin (canonical names).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from core.constants import CMU_UNIT_M
from core.motion.bvh import BvhClip, clip_to_motion, euler_to_matrix, read_bvh, write_bvh
from core.motion.load import Z_UP_TO_Y_UP, load_motion
from core.motion.mapping import MAPPED_JOINTS, canonical_positions, clean_names, map_skeleton
from core.motion.procedural import make_motion
from core.skeleton import CANONICAL_JOINTS
from tests.conftest import assert_close
from tests.data_bvh import cmu_as, write_raw_bvh

FRAMES = 60
POS = ["Xposition", "Yposition", "Zposition"]
ROT = ["Zrotation", "Xrotation", "Yrotation"]


@pytest.fixture(scope="module")
def sources(bvh_dir, tmp_path_factory) -> dict[str, Path]:
    """Undecorated files, ``FRAMES`` frames each: ``cmu``, ``biped``, ``mixamo``, ``rigify``,
    ``canonical`` (rewritten by :func:`write_clip`, the writer the decorated files use)."""
    out = tmp_path_factory.mktemp("plain")
    files = {"cmu": out / "cmu.bvh"}
    write_clip(files["cmu"], _first_frames(read_bvh(bvh_dir / "01_01.bvh")))
    for style in ("biped", "mixamo", "rigify"):
        files[style] = out / f"{style}.bvh"
        cmu_as(style, bvh_dir / "01_01.bvh", files[style], slice(0, FRAMES))
    write_bvh(out / "dance_raw.bvh", make_motion("dance", FRAMES, 30.0, 0))
    files["canonical"] = out / "canonical.bvh"
    write_clip(files["canonical"], read_bvh(out / "dance_raw.bvh"))
    return files


def _first_frames(clip: BvhClip) -> BvhClip:
    return replace(clip, values=clip.values[:FRAMES])


def write_clip(
    path: Path,
    clip: BvhClip,
    rename: Callable[[int, str], str] = lambda k, n: n,
    wrapper: tuple[str, np.ndarray, list[str], np.ndarray] | None = None,
) -> dict[str, str]:
    """Write ``clip`` with joint ``k`` named ``rename(k, name)``, optionally below a new root
    ``wrapper = (name, offset (3,), channels, values (T, C))``. Returns {old name: new name}."""
    names = [rename(k, n) for k, n in enumerate(clip.names)]
    parents = list(clip.parents)
    offsets = clip.offsets
    channels = [list(c) for c in clip.channels]
    values = clip.values
    ends = {k: clip.end_sites[k] for k in np.flatnonzero(clip.has_end_site)}
    if wrapper is not None:
        w_name, w_offset, w_channels, w_values = wrapper
        names = [w_name, *names]
        parents = [-1] + [p + 1 if p >= 0 else 0 for p in parents]
        offsets = np.vstack([w_offset, offsets])
        channels = [w_channels, *channels]
        values = np.hstack([np.asarray(w_values, np.float64).reshape(len(values), -1), values])
        ends = {k + 1: v for k, v in ends.items()}
    write_raw_bvh(path, names, parents, offsets, ends, channels, values, clip.frame_time)
    return dict(zip(clip.names, names[1:] if wrapper else names))


def _still(name: str, offset=(0.0, 0.0, 0.0), angles=(0.0, 0.0, 0.0)):
    """A static wrapper root: 6 constant channels (ZXY angles in degrees)."""
    row = np.array([*offset, *angles], np.float64)
    return name, np.asarray(offset, np.float64), POS + ROT, np.tile(row, (FRAMES, 1))


# Decorations: (source, rename(k, name), wrapper or None, rig label).
_BIPED_SUFFIX = ("biped", lambda k, n: f"{n}_{k + 180}", None, "biped")
_DECORATIONS = {
    "biped_suffix": _BIPED_SUFFIX,
    "biped_gltf_underscores": (
        "biped",
        lambda k, n: f"{n.replace(' ', '_')}_{k + 3}",
        _still("RootNode"),
        "biped",
    ),
    "mixamo_namespace_1": (
        "mixamo",
        lambda k, n: n.replace("mixamorig:", "mixamorig1:"),
        None,
        "mixamo",
    ),
    "mixamo_namespace_9_common_suffix": (
        "mixamo",
        lambda k, n: n.replace("mixamorig:", "mixamorig9:") + "_01",
        None,
        "mixamo",
    ),
    "mixamo_blender_path": ("mixamo", lambda k, n: f"Armature|{n}", None, "mixamo"),
    "cmu_blender_path_and_duplicate": ("cmu", lambda k, n: f"Armature|{n}.001", None, "cmu"),
    "cmu_slash_path": ("cmu", lambda k, n: f"Armature/{n}", None, "cmu"),
    "cmu_nested_namespaces": ("cmu", lambda k, n: f"rig:char:{n}", None, "cmu"),
    "rigify_blender_path": ("rigify", lambda k, n: f"Armature|{n}", None, "rigify"),
    "rigify_suffix": ("rigify", lambda k, n: f"{n}_{k + 40}", None, "rigify"),
    "canonical_blender_path": ("canonical", lambda k, n: f"Armature|{n}", None, "canonical"),
    "canonical_gltf_root": (
        "canonical",
        lambda k, n: n,
        _still("GLTF_created_0_rootJoint"),
        "canonical",
    ),
    "cmu_gltf_root_suffix": (
        "cmu",
        lambda k, n: f"{n}_{k + 1}",
        _still("GLTF_created_0_rootJoint"),
        "cmu",
    ),
    "mixamo_armature_root": ("mixamo", lambda k, n: n, _still("Armature"), "mixamo"),
}


@pytest.mark.parametrize("kind", list(_DECORATIONS))
def test_decorated_names_map_like_the_plain_file(kind, sources, tmp_path, dng):
    source, rename, wrapper, rig = _DECORATIONS[kind]
    plain = sources[source]
    path = tmp_path / f"{kind}.bvh"
    renamed = write_clip(path, read_bvh(plain), rename, wrapper)
    assert wrapper or set(renamed.values()) != set(renamed)  # something is decorated

    code, out, err = dng("motion", "info", path, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert set(info["joints"]) == set(CANONICAL_JOINTS)
    assert info["rig"] == rig
    assert info["wrapper_joints"] == ([wrapper[0]] if wrapper else [])

    a, b = load_motion(plain), load_motion(path)
    # Every canonical joint comes from the decorated twin of the plain file's source joint.
    for c in MAPPED_JOINTS:
        expected = tuple(
            (renamed[n], w) for n, w in a.meta["joint_mapping"].sources[MAPPED_JOINTS.index(c)]
        )
        assert b.meta["joint_mapping"].sources[MAPPED_JOINTS.index(c)] == expected, c
    assert b.meta["unit_scale"] == a.meta["unit_scale"]
    assert b.meta["up_axis"] == a.meta["up_axis"]
    assert b.skeleton.names == tuple(renamed[n] for n in a.skeleton.names)
    assert_close(b.joint_positions(), a.joint_positions(), atol=1e-6, what=f"{kind} joints")
    assert_close(canonical_positions(b), canonical_positions(a), atol=1e-6, what=kind)


def test_retarget_of_a_decorated_file(sources, tmp_path, dng):
    path = tmp_path / "gltf_mixamo.bvh"
    write_clip(
        path,
        read_bvh(sources["mixamo"]),
        lambda k, n: n.replace("mixamorig:", "mixamorig1:") + f".{k:03d}",
        _still("GLTF_created_0_rootJoint"),
    )
    out = tmp_path / "out.bvh"
    code, stdout, err = dng("motion", "retarget", path, "--out", out)
    assert code == 0, err
    assert "mixamo rig" in stdout
    assert load_motion(out).meta["rig"] == "canonical"


# ------------------------------------------------------------------------------ wrapper roots


def test_wrapper_turning_y_up_into_z_up_with_an_offset(sources, tmp_path):
    """glTF's Y-up to Z-up wrapper (+90 degrees about X) with an offset: the loader detects Z up,
    and its conversion back gives the plain file's positions shifted by the offset (horizontal
    here, so that the floor and the standing height stay)."""
    offset = np.array([12.5, -3.25, 0.0])
    plain = sources["cmu"]
    path = tmp_path / "z_up.bvh"
    write_clip(
        path, read_bvh(plain), wrapper=_still("GLTF_created_0_rootJoint", offset, (0, 90, 0))
    )
    raw_a, raw_b = clip_to_motion(read_bvh(plain)), clip_to_motion(read_bvh(path))
    rx = euler_to_matrix(np.array([[90.0]]), "X")[0]
    expected = offset + raw_a.joint_positions().astype(np.float64) @ rx.T
    extent = float(np.abs(expected).max())
    assert_close(raw_b.joint_positions(), expected, atol=1e-6 * extent, what="file units")

    a, b = load_motion(plain), load_motion(path)
    assert a.meta["up_axis"] == "y" and b.meta["up_axis"] == "z"
    assert b.meta["unit_scale"] == a.meta["unit_scale"] == CMU_UNIT_M
    shift = Z_UP_TO_Y_UP @ offset * CMU_UNIT_M
    assert_close(b.joint_positions(), a.joint_positions() + shift, atol=1e-6, what="metres")
    assert b.meta["standing_height_m"] == pytest.approx(a.meta["standing_height_m"], abs=1e-6)


def test_animated_wrapper_is_composed_per_frame(sources, tmp_path):
    """A wrapper that moves and turns about Y every frame, above hips that move too."""
    t = np.arange(FRAMES, dtype=np.float64)
    w_pos = np.stack([0.25 * t, 5.0 + 0.5 * np.sin(t / 8).round(6), -0.125 * t], axis=1)
    w_ang = np.stack([np.zeros(FRAMES), np.zeros(FRAMES), 1.5 * t], axis=1)  # Z X Y degrees
    wrapper = ("Armature", w_pos[0], POS + ROT, np.hstack([w_pos, w_ang]))
    path = tmp_path / "animated.bvh"
    write_clip(path, read_bvh(sources["biped"]), lambda k, n: f"{n}_{k + 7}", wrapper)
    raw_a = clip_to_motion(read_bvh(sources["biped"]))
    raw_b = clip_to_motion(read_bvh(path))
    assert raw_b.meta["wrapper_joints"] == ["Armature"]
    rot = euler_to_matrix(w_ang, "ZXY")
    expected = w_pos[:, None] + np.einsum("tab,tjb->tja", rot, raw_a.joint_positions())
    extent = float(np.abs(expected).max())
    assert_close(raw_b.joint_positions(), expected, atol=1e-6 * extent, what="animated wrapper")
    assert "varying_translations" not in raw_b.meta  # nothing averaged away


def test_hips_below_a_wrapper_keeps_its_path(sources, tmp_path):
    """Without folding, the hips' varying translation would be replaced by its mean."""
    path = tmp_path / "gltf.bvh"
    write_clip(path, read_bvh(sources["cmu"]), wrapper=_still("GLTF_created_0_rootJoint"))
    m = load_motion(path)
    assert m.skeleton.names[0] == "Hips" and m.meta["mapping"]["Hips"] == "Hips"
    path_length = np.linalg.norm(np.diff(m.root_positions, axis=0), axis=1).sum()
    assert path_length > 0.01  # metres over 0.5 s of walking
    assert_close(m.root_positions, load_motion(sources["cmu"]).root_positions, atol=1e-6)


def test_a_body_joint_is_never_folded(tmp_path):
    """A hips root with one child whose translation varies keeps both (mean, said so)."""
    clip = BvhClip(
        names=("Hips", "Spine"),
        parents=np.array([-1, 0]),
        offsets=np.array([[0.0, 90, 0], [0, 20, 0]]),
        end_sites=np.array([[0.0, 0, 0], [0, 60, 0]]),
        has_end_site=np.array([False, True]),
        channels=(tuple(POS + ROT), tuple(POS + ROT)),
        frame_time=1 / 30,
        values=np.array([[0, 90, 0, 0, 0, 0, 0, y, 0, 0, 0, 0] for y in (20.0, 25.0, 30.0)]),
    )
    m = clip_to_motion(clip)
    assert m.skeleton.names == ("Hips", "Spine") and m.meta["wrapper_joints"] == []
    assert m.meta["varying_translations"] == {"Spine": pytest.approx(5.0)}


# ------------------------------------------------------------------------- false matches


@pytest.mark.parametrize(
    "names, cleaned",
    [
        # Suffixes with a body-joint name left: stripped; sides kept apart.
        (
            ("Bip001 L Clavicle_197", "Bip001 R Clavicle_198", "Bip001 L Finger0_12", "Bip001_1"),
            ("Bip001 L Clavicle", "Bip001 R Clavicle", "Bip001 L Finger0_12", "Bip001_1"),
        ),
        # Digits that are part of the name stay.
        (
            ("Spine1", "Spine2", "Neck1", "LeftHandIndex1", "LeftHand", "f_index.01.L"),
            ("Spine1", "Spine2", "Neck1", "LeftHandIndex1", "LeftHand", "f_index.01.L"),
        ),
        (
            ("Spine1_7", "Spine2_8", "Neck1_9", "LeftHandIndex1_10", "LeftHand_11"),
            ("Spine1", "Spine2", "Neck1", "LeftHandIndex1_10", "LeftHand"),
        ),
        # One suffix on every joint: an exporter's, stripped everywhere.
        (
            ("mixamorig:Hips_01", "mixamorig:LeftHandIndex1_01", "mixamorig:Neck1_01"),
            ("Hips", "LeftHandIndex1", "Neck1"),
        ),
        # Stripping would make two joints read the same: kept.
        (
            ("DEF-spine", "DEF-spine.001", "DEF-spine.002", "DEF-spine.003"),
            ("DEF-spine", "DEF-spine.001", "DEF-spine.002", "DEF-spine.003"),
        ),
        (("pelvis", "spine_01", "spine_02", "neck_01"), ("pelvis", "spine_01", "spine_02", "neck")),
        (
            ("LeftArm", "LeftArm.001", "LeftHand", "LeftHand_1"),
            ("LeftArm", "LeftArm.001", "LeftHand", "LeftHand_1"),
        ),
        (
            ("DEF-spine_4", "DEF-spine.001_5", "DEF-spine.002_6"),
            ("DEF-spine", "DEF-spine.001", "DEF-spine.002"),
        ),
        # Paths and namespaces.
        (
            ("Armature|Hips", "Armature/Spine", "rig:char:Spine2", "mixamorig9:LeftArm"),
            ("Hips", "Spine", "Spine2", "LeftArm"),
        ),
        # Unknown names keep their digits.
        (("Bone_12", "Bone.013", "Joint_2"), ("Bone_12", "Bone.013", "Joint_2")),
    ],
)
def test_clean_names(names, cleaned):
    assert clean_names(names) == cleaned


def test_hand_is_not_a_finger_and_sides_stay_apart(sources, tmp_path):
    """Decorated twins of the hand and the finger: the hand is still the hand, left stays left."""
    path = tmp_path / "twins.bvh"
    renamed = write_clip(path, read_bvh(sources["mixamo"]), lambda k, n: f"{n}_{k + 50}")
    mapping = load_motion(path).meta["mapping"]
    for side in ("Left", "Right"):
        assert mapping[f"{side}Hand"] == renamed[f"mixamorig:{side}Hand"]
        assert mapping[f"{side}Arm"] == renamed[f"mixamorig:{side}Arm"]
    biped = load_motion(sources["biped"])
    path = tmp_path / "biped.bvh"
    renamed = write_clip(path, read_bvh(sources["biped"]), _BIPED_SUFFIX[1])
    mapping = load_motion(path).meta["mapping"]
    for c, source in biped.meta["mapping"].items():
        sided = re.findall(r"Bip001 ([LR]) ", mapping[c])
        assert sided == re.findall(r"Bip001 ([LR]) ", source), c


# -------------------------------------------------------------------------------- unknown rigs


def _missing(err: str) -> set[str]:
    m = re.search(r"(\d+) of 19 not found: ([A-Za-z0-9, ]+) \(naming convention", err)
    assert m, err
    found = set(m.group(2).split(", "))
    assert int(m.group(1)) == len(found)
    return found


def test_unknown_rig_lists_exactly_the_missing_joints(sources, tmp_path, dng):
    """CMU with the left arm's joints renamed to bones, and suffixes and a wrapper elsewhere."""
    arm = {"LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand"}
    path = tmp_path / "left_arm_unknown.bvh"
    write_clip(
        path,
        read_bvh(sources["cmu"]),
        lambda k, n: f"Bone_{k}" if n in arm else f"{n}_{k + 1}",
        _still("GLTF_created_0_rootJoint"),
    )
    code, out, err = dng("motion", "info", path)
    assert code == 2 and out == ""
    assert err.strip().count("\n") == 0
    assert str(path) in err
    assert _missing(err) == arm


def test_a_rig_of_unknown_names_misses_all_19(sources, tmp_path, dng):
    path = tmp_path / "bones.bvh"
    write_clip(path, read_bvh(sources["canonical"]), lambda k, n: f"Bone_{k:02d}")
    for action in (("info",), ("retarget", "--out", tmp_path / "out.bvh")):
        code, out, err = dng("motion", action[0], path, *action[1:])
        assert code == 2 and err.strip().count("\n") == 0 and str(path) in err
        assert _missing(err) == set(CANONICAL_JOINTS)
    assert not (tmp_path / "out.bvh").exists()
    with pytest.raises(Exception, match="19 of 19 not found"):
        map_skeleton(clip_to_motion(read_bvh(path)).skeleton, path=path)
