"""Motion import: BVH reading/writing, units and up axis, mapping onto the canonical joints,
resampling. Real CMU and Motive capture, plus CMU clips converted to other tools' conventions."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.body.shape import BodyShape, mannequin_skeleton
from core.constants import CMU_UNIT_M
from core.errors import InputError
from core.motion.bvh import clip_to_motion, euler_to_matrix, read_bvh, write_bvh
from core.motion.load import (
    load_motion,
    resample,
    root_travel,
    standing_height,
)
from core.motion.mapping import (
    MAPPED_JOINTS,
    canonical_joints,
    canonical_positions,
    map_skeleton,
    split_name,
)
from core.motion.motion import Motion
from core.skeleton import CANONICAL_JOINTS
from tests.conftest import assert_close
from tests.data_bvh import BIPED_UNIT_M, cmu_as, tiny_bvh_text

FRAMES = slice(0, 240)


@pytest.fixture(scope="module")
def cmu(bvh_dir) -> Motion:
    return load_motion(bvh_dir / "01_01.bvh")


@pytest.fixture(scope="module")
def converted(bvh_dir, tmp_path_factory) -> dict[str, tuple[Path, dict]]:
    out = tmp_path_factory.mktemp("other_tools")
    files = {}
    for style in ("biped", "mixamo", "rigify"):
        path = out / f"01_01_{style}.bvh"
        files[style] = (path, cmu_as(style, bvh_dir / "01_01.bvh", path, FRAMES))
    return files


def _slice(motion: Motion, frames: slice) -> Motion:
    return replace(
        motion, rotations=motion.rotations[frames], root_positions=motion.root_positions[frames]
    )


# ---------------------------------------------------------------------------------- parsing


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_euler_channels_compose_intrinsically_in_listed_order(order, rng):
    angles = rng.uniform(-170, 170, (20, 3))
    expected = Rotation.from_euler(order, angles, degrees=True).as_matrix()  # intrinsic
    assert_close(euler_to_matrix(angles, order), expected, atol=1e-12, what=order)
    # R = R_c1 @ R_c2 @ R_c3, written out for one order.
    if order == "ZXY":
        rz, rx, ry = (euler_to_matrix(angles[:, [k]], a) for k, a in enumerate("ZXY"))
        assert_close(euler_to_matrix(angles, order), rz @ rx @ ry, atol=1e-12)


def test_cmu_hierarchy_channels_and_fps(bvh_dir):
    clip = read_bvh(bvh_dir / "01_01.bvh")
    assert clip.names[0] == "Hips" and len(clip.names) == 31
    assert clip.channels[0] == (
        "Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation",
    )  # fmt: skip
    assert clip.values.shape == (2752, 96)
    assert clip.fps == 120.0  # "Frame Time: .0083333" snaps to 120
    head = clip.names.index("Head")
    assert clip.has_end_site[head] and clip.end_sites[head][1] > 1.7


def test_crlf_tabs_bom_and_lowercase_keywords(tmp_path):
    text = tiny_bvh_text(frames=4, newline="\r\n").replace("End Site", "end site")
    path = tmp_path / "crlf.bvh"
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    clip = read_bvh(path)
    assert clip.names == ("Hips", "Spine") and clip.num_frames == 4
    assert_close(clip.end_sites[1], [0, 60, 0])
    assert_close(clip.values[3], [3, 90, 0, 6, 0, 0, 0, 9, 0])


def test_root_position_channels_are_world_positions(tmp_path):
    path = tmp_path / "tiny.bvh"
    path.write_text(tiny_bvh_text(frames=3))
    m = clip_to_motion(read_bvh(path))
    assert_close(m.root_positions[:, 0], [0, 1, 2])
    assert_close(m.root_positions[:, 1], [90, 90, 90])
    # Frame 2: root turned 4 degrees about Z; the spine joint sits 20 up in its frame.
    pos = m.joint_positions()
    a = np.radians(4.0)
    assert_close(pos[2, 1], [2 - 20 * np.sin(a), 90 + 20 * np.cos(a), 0], atol=1e-4)


def _six_channel_spine(values_spine_y: list[float]) -> str:
    lines = tiny_bvh_text(frames=len(values_spine_y)).splitlines()
    k = lines.index("\t\tCHANNELS 3 Zrotation Xrotation Yrotation")
    lines[k] = "\t\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"
    motion_at = lines.index("MOTION") + 3
    for t, y in enumerate(values_spine_y):
        lines[motion_at + t] = f"0 90 0 0 0 0 0 {y} 0 0 0 0"
    return "\n".join(lines) + "\n"


def test_non_root_position_channels(tmp_path):
    # Constant: the channel is the offset (3ds Max Biped writes the offset there, OFFSET may differ).
    path = tmp_path / "const.bvh"
    path.write_text(_six_channel_spine([25.0, 25.0, 25.0]))
    m = clip_to_motion(read_bvh(path))
    assert_close(m.skeleton.offsets[1], [0, 25, 0])
    assert "varying_translations" not in m.meta
    # Varying: replaced by the mean, and said so.
    path = tmp_path / "vary.bvh"
    path.write_text(_six_channel_spine([20.0, 25.0, 30.0]))
    m = clip_to_motion(read_bvh(path))
    assert_close(m.skeleton.offsets[1], [0, 25, 0])
    assert m.meta["varying_translations"] == {"Spine": pytest.approx(5.0)}


# ---------------------------------------------------------------------------------- mapping


@pytest.mark.parametrize(
    "name, side, core",
    [
        ("mixamorig:LeftForeArm", "L", "forearm"),
        ("mixamorig1:RightUpLeg", "R", "upleg"),
        ("Bip001 R Calf", "R", "calf"),
        ("Bip001 Pelvis", None, "pelvis"),
        ("DEF-upper_arm.L", "L", "upperarm"),
        ("DEF-spine.003", None, "spine003"),
        ("LHipJoint", "L", "hipjoint"),
        ("RThumb", "R", "thumb"),
        ("lShldr", "L", "shldr"),
        ("thigh_r", "R", "thigh"),
    ],
)
def test_split_name(name, side, core):
    assert split_name(name) == (side, core)


def test_cmu_maps_to_19_joints(cmu):
    m = cmu.meta["mapping"]
    assert set(m) == set(MAPPED_JOINTS)
    assert cmu.meta["rig"] == "cmu"
    assert m["Hips"] == "Hips" and m["LeftArm"] == "LeftArm" and m["RightFoot"] == "RightFoot"
    assert m["LeftUpLeg"] == "LeftUpLeg"  # not the zero-length LHipJoint
    assert m["Neck"] == "Neck1"  # CMU's Neck sits on Spine1
    assert m["Spine"] == "Spine" and m["Spine2"] == "Spine1"


def test_no_canonical_bone_has_zero_length(cmu):
    pos = canonical_positions(_slice(cmu, slice(0, 1)))[0]
    skel = mannequin_skeleton()
    for k, name in enumerate(skel.names[1:], start=1):
        parent = skel.names[skel.parents[k]]
        d = np.linalg.norm(pos[MAPPED_JOINTS.index(name)] - pos[MAPPED_JOINTS.index(parent)])
        assert d > 0.02, f"{parent}->{name} is {d:.4f} m"


def test_motive_names_shoulder_is_upper_arm(bvh_dir):
    m = load_motion(bvh_dir / "Boxing_Toes.bvh")
    mp = m.meta["mapping"]
    assert m.meta["rig"] == "motive"
    assert mp["LeftShoulder"] == "LeftCollar" and mp["LeftArm"] == "LeftShoulder"
    assert mp["LeftForeArm"] == "LeftElbow" and mp["LeftHand"] == "LeftWrist"
    assert mp["RightUpLeg"] == "RightHip" and mp["RightFoot"] == "RightAnkle"
    assert mp["Spine"] == "Ab" and mp["Spine2"] == "Chest"
    assert m.meta["unit"] == "cm" and m.meta["up_axis"] == "y"
    assert 1.6 < m.meta["standing_height_m"] < 1.85


def test_mannequin_maps_to_itself():
    mapping = map_skeleton(mannequin_skeleton())
    assert mapping.rig == "canonical"
    assert mapping.as_dict() == {c: c for c in MAPPED_JOINTS}


def test_canonical_positions_shapes_and_order(cmu):
    short = _slice(cmu, slice(0, 10))
    pos = canonical_positions(short)
    assert pos.shape == (10, 20, 3) and pos.dtype == np.float32
    joints, root = canonical_joints(short)
    assert joints.shape == (10, 19, 3) and root.shape == (10, 3)
    world = short.joint_positions()
    names = short.skeleton.names
    assert_close(root, world[:, names.index("Hips")])
    assert_close(
        joints[:, CANONICAL_JOINTS.index("LeftForeArm")], world[:, names.index("LeftForeArm")]
    )


# ------------------------------------------------------------------------ units and up axis


def test_cmu_units_axis_height_and_travel(cmu):
    assert cmu.meta["up_axis"] == "y"
    assert cmu.meta["unit"] == "cmu" and cmu.meta["unit_scale"] == CMU_UNIT_M
    # Head end site to the capture's ground plane: 1.54 m (the toe joints float 3.8 cm above it).
    assert 1.5 <= cmu.meta["standing_height_m"] <= 1.9
    path, net = root_travel(cmu)
    assert path >= net > 1.0  # the subject walks about
    assert cmu.fps == 120.0 and cmu.num_frames == 2752


@pytest.mark.parametrize("style", ["biped", "mixamo", "rigify"])
def test_other_tools_map_and_match_the_cmu_clip(style, converted, cmu):
    path, info = converted[style]
    m = load_motion(path)
    assert set(m.meta["mapping"]) == set(MAPPED_JOINTS)
    assert m.meta["up_axis"] == info["up"]
    assert m.meta["rig"] == style
    true_height = cmu.meta["standing_height_m"]
    if style == "biped":
        assert m.meta["unit"] == "estimated"
        assert m.meta["standing_height_m"] == pytest.approx(1.70, rel=1e-6)
    else:
        assert m.meta["unit"] == {"mixamo": "cm", "rigify": "m"}[style]
        assert m.meta["standing_height_m"] == pytest.approx(true_height, rel=0.10)
    # With the true unit, every canonical joint follows the CMU clip (axes converted back).
    exact = load_motion(path, scale=info["unit_m"])
    assert exact.meta["unit_scale"] == info["unit_m"]
    expected = canonical_positions(_slice(cmu, FRAMES))
    assert_close(canonical_positions(exact), expected, atol=1e-4, what=style)


def test_scale_override_wins(bvh_dir, cmu):
    m = load_motion(bvh_dir / "01_01.bvh", scale=0.05)
    assert m.meta["unit"] == "user" and m.meta["unit_scale"] == 0.05
    expected = cmu.meta["standing_height_m"] * 0.05 / CMU_UNIT_M
    assert m.meta["standing_height_m"] == pytest.approx(expected, rel=1e-5)


def test_mannequin_standing_height_is_its_height():
    sk = mannequin_skeleton(BodyShape(height=1.83))
    still = Motion(sk, np.broadcast_to(np.eye(3, dtype=np.float32), (2, 20, 3, 3)).copy(),
                   np.tile(sk.offsets[0], (2, 1)), fps=30.0)  # fmt: skip
    assert standing_height(still) == pytest.approx(1.83, abs=1e-5)


def test_root_travel_square():
    sk = mannequin_skeleton()
    xz = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    root = np.stack([xz[:, 0], np.full(4, 0.9, np.float32), xz[:, 1]], axis=1)
    m = Motion(sk, np.broadcast_to(np.eye(3, dtype=np.float32), (4, 20, 3, 3)).copy(), root, 30.0)
    path, net = root_travel(m)
    assert path == pytest.approx(3.0) and net == pytest.approx(1.0)


# ------------------------------------------------------------------------------ user mapping


def _renamed_rigify(converted, tmp_path) -> tuple[Path, dict[str, str]]:
    src, _ = converted["rigify"]
    renames = {"DEF-upper_arm.L": "Bone07", "DEF-forearm.L": "Bone08", "DEF-shin.R": "Bone19"}
    text = src.read_text()
    for old, new in renames.items():
        text = text.replace(f"JOINT {old}\n", f"JOINT {new}\n")
    path = tmp_path / "odd.bvh"
    path.write_text(text)
    return path, renames


def test_unknown_rig_names_the_missing_joints(converted, tmp_path):
    path, _ = _renamed_rigify(converted, tmp_path)
    with pytest.raises(InputError) as exc:
        load_motion(path)
    msg = str(exc.value)
    assert str(path) in msg
    assert "LeftArm" in msg and "LeftForeArm" in msg and "RightLeg" in msg
    assert "LeftHand," not in msg  # found through the name


def test_user_mapping_file(converted, tmp_path, cmu):
    path, renames = _renamed_rigify(converted, tmp_path)
    mapping = tmp_path / "map.json"
    mapping.write_text(
        json.dumps({"LeftArm": "Bone07", "LeftForeArm": "Bone08", "RightLeg": "Bone19"})
    )
    m = load_motion(path, mapping=mapping)
    assert m.meta["mapping"]["LeftArm"] == "Bone07" and m.meta["rig"] == "rigify+user"
    assert_close(canonical_positions(m), canonical_positions(_slice(cmu, FRAMES)), atol=1e-4)


@pytest.mark.parametrize(
    "content, problem",
    [
        ("{not json", "not valid JSON"),
        ('["LeftArm"]', "JSON object"),
        ('{"LeftElbow": "Bone07"}', "unknown canonical joints"),
        ('{"LeftArm": "NoSuchBone"}', "does not have"),
    ],
)
def test_bad_mapping_file(content, problem, converted, tmp_path):
    path, _ = _renamed_rigify(converted, tmp_path)
    mapping = tmp_path / "map.json"
    mapping.write_text(content)
    with pytest.raises(InputError, match=problem) as exc:
        load_motion(path, mapping=mapping)
    assert str(mapping) in str(exc.value)


# ----------------------------------------------------------------------------- resampling


def test_resample_120_to_30_keeps_duration(cmu):
    short = _slice(cmu, slice(0, 481))
    out = resample(short, 30.0)
    assert out.fps == 30.0
    assert out.num_frames == round(480 * 30 / 120) + 1 == 121
    assert out.duration == pytest.approx(short.duration)
    # Every 4th source frame lands exactly on an output frame.
    assert_close(out.joint_positions(), short.joint_positions()[::4], atol=1e-5)


def test_resample_interpolates_between_frames(cmu):
    short = _slice(cmu, slice(0, 121))
    out = resample(short, 50.0)  # 120 -> 50 fps: most output frames fall between source frames
    assert out.num_frames == 51 and out.duration == pytest.approx(short.duration)
    times = np.arange(51) / 50.0
    src_t = np.arange(121) / 120.0
    expected_root = np.stack(
        [np.interp(times, src_t, short.root_positions[:, a]) for a in range(3)], 1
    )
    assert_close(out.root_positions, expected_root, atol=1e-5)
    # Slerp stays on the rotation group and between its neighbours.
    r = out.rotations.astype(np.float64)
    assert_close(r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape), atol=1e-5)
    k = 12  # t = 0.24 s, between source frames 28 and 29
    lo, hi = short.rotations[28].astype(np.float64), short.rotations[29].astype(np.float64)
    gap = np.linalg.norm(lo - hi, axis=(1, 2))
    assert (np.linalg.norm(r[k] - lo, axis=(1, 2)) <= gap + 1e-5).all()


def test_load_motion_fps_argument(bvh_dir):
    m = load_motion(bvh_dir / "01_03.bvh", fps=30)
    assert m.fps == 30.0 and m.meta["source_fps"] == 120.0
    assert m.num_frames == round((4511 - 1) * 30 / 120) + 1


# ----------------------------------------------------------------------------- round trip


@pytest.mark.parametrize("order", ["ZXY", "XYZ"])
def test_read_write_read_reproduces_joint_positions(order, cmu, tmp_path):
    short = _slice(cmu, slice(0, 300))
    path = tmp_path / f"rt_{order}.bvh"
    write_bvh(path, short, order=order)
    back = load_motion(path)
    assert back.meta["unit"] == "m" and back.meta["up_axis"] == "y"
    assert back.num_frames == 300 and back.fps == 120.0
    assert back.skeleton.names == short.skeleton.names
    assert_close(back.joint_positions(), short.joint_positions(), atol=1e-4, what=order)
    assert back.meta["mapping"] == short.meta["mapping"]


def test_round_trip_of_a_z_up_biped_file(converted, tmp_path):
    path, _ = converted["biped"]
    m = load_motion(path)
    out = tmp_path / "biped_yup.bvh"
    write_bvh(out, m)
    back = load_motion(out, scale=1.0)
    assert back.meta["up_axis"] == "y"
    assert_close(back.joint_positions(), m.joint_positions(), atol=1e-4)


def test_write_is_atomic_on_failure(cmu, tmp_path):
    path = tmp_path / "x.bvh"
    with pytest.raises(ValueError):
        write_bvh(path, _slice(cmu, slice(0, 2)), order="YZX")
    assert not path.exists() and not list(tmp_path.iterdir())


def test_biped_scale_is_estimated_from_a_170_cm_person(converted, cmu):
    path, _ = converted["biped"]
    m = load_motion(path)
    # The file's person is really cmu-height tall; the estimate scales them to 1.70 m.
    true_height = cmu.meta["standing_height_m"]
    assert m.meta["unit_scale"] == pytest.approx(BIPED_UNIT_M * 1.70 / true_height, rel=1e-4)
    exact = load_motion(path, scale=BIPED_UNIT_M)
    assert exact.meta["unit"] == "user"
    assert exact.meta["standing_height_m"] == pytest.approx(true_height, rel=1e-4)


def _skeleton(joints: list[tuple[str, str | None, tuple[float, float, float]]]):
    """A skeleton from (name, parent name, rest world position) triples, parents first."""
    from core.skeleton import Skeleton

    names = tuple(j[0] for j in joints)
    parents = np.array([-1 if p is None else names.index(p) for _, p, _ in joints], np.int64)
    world = np.array([j[2] for j in joints], np.float64)
    offsets = np.array([w if p < 0 else w - world[p] for w, p in zip(world, parents)])
    return Skeleton(names, parents, offsets.astype(np.float32), np.zeros_like(world, np.float32))


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_spine_chains_of_1_to_4_joints(n):
    spine = [f"Spine{k}" if k else "Spine" for k in range(n)]
    ys = np.linspace(1.05, 1.40, n + 2)[1:-1]
    joints = [("Hips", None, (0, 1.0, 0))]
    joints += [(s, joints[-1 - 0][0] if k == 0 else spine[k - 1], (0, y, 0))
               for k, (s, y) in enumerate(zip(spine, ys))]  # fmt: skip
    chest = spine[-1]
    joints += [("Neck", chest, (0, 1.45, 0)), ("Head", "Neck", (0, 1.55, 0))]
    for side, x in (("Left", 1), ("Right", -1)):
        joints += [
            (f"{side}Shoulder", chest, (0.05 * x, 1.40, 0)),
            (f"{side}Arm", f"{side}Shoulder", (0.18 * x, 1.40, 0)),
            (f"{side}ForeArm", f"{side}Arm", (0.45 * x, 1.40, 0)),
            (f"{side}Hand", f"{side}ForeArm", (0.70 * x, 1.40, 0)),
            (f"{side}UpLeg", "Hips", (0.1 * x, 0.95, 0)),
            (f"{side}Leg", f"{side}UpLeg", (0.1 * x, 0.5, 0)),
            (f"{side}Foot", f"{side}Leg", (0.1 * x, 0.08, 0)),
        ]
    sk = _skeleton(joints)
    mapping = map_skeleton(sk)
    assert mapping.primary("Spine2") == chest
    if n >= 2:
        assert mapping.source_of("Spine") == "Spine"
    if n == 3:
        assert mapping.source_of("Spine1") == "Spine1"
    rest = sk.rest_positions().astype(np.float64)
    heights = mapping.weights(sk.names) @ rest[:, 1]
    order = [MAPPED_JOINTS.index(c) for c in ("Hips", "Spine", "Spine1", "Spine2", "Neck", "Head")]
    assert (np.diff(heights[order]) > 0).all(), heights[order]
