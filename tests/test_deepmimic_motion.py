"""DeepMimic motion in: a file written here from known rotations, pybullet's real captures, bad
input, looping, and ``dng motion`` on it.

pybullet (a dev dependency, installed by ``./studio setup``) ships DeepMimic's clips in
``pybullet_data/data/motions``: motion capture of other subjects than CMU's (walking, running,
dancing, spinning). A missing pybullet is a setup error, not a skip.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.errors import InputError
from core.motion.deepmimic import (
    DEEPMIMIC_JOINTS,
    FRAME_SIZE,
    deepmimic_skeleton,
    read_deepmimic,
)
from core.motion.load import load_motion
from core.motion.mapping import MAPPED_JOINTS, canonical_positions
from core.skeleton import forward_kinematics
from tests.conftest import assert_motion_file_refused

#: Keyframe columns of the ball joints' quaternions and the hinges' angles (the module's layout,
#: written out again here from DeepMimic's documentation).
BALLS = {"Chest": 8, "Neck": 12, "RightUpLeg": 16, "RightFoot": 21, "RightArm": 25,
         "LeftUpLeg": 30, "LeftFoot": 35, "LeftArm": 39}  # fmt: skip
HINGES = {"RightLeg": 20, "RightForeArm": 29, "LeftLeg": 34, "LeftForeArm": 43}


def _known_clip(t: int = 12, seed: int = 0) -> tuple[dict, np.ndarray, np.ndarray]:
    """A DeepMimic document from random rotations, and the rotations and root it holds:
    (doc, (t, J, 3, 3) local rotations on :func:`deepmimic_skeleton`, (t, 3) root)."""
    rng = np.random.default_rng(seed)
    skel = deepmimic_skeleton()
    rot = np.broadcast_to(np.eye(3), (t, skel.num_joints, 3, 3)).copy()
    root = np.column_stack(
        [rng.normal(size=t), 0.9 + 0.05 * rng.normal(size=t), rng.normal(size=t)]
    )
    frames = np.zeros((t, FRAME_SIZE))
    frames[:, 0] = 1.0 / 30.0
    frames[:, 1:4] = root
    for name, col in {"Hips": 4, **BALLS}.items():
        r = Rotation.random(t, random_state=rng)
        xyzw = r.as_quat()
        frames[:, col : col + 4] = np.column_stack([xyzw[:, 3], xyzw[:, :3]]) * rng.uniform(0.5, 2)
        rot[:, skel.index(name)] = r.as_matrix()
    for name, col in HINGES.items():
        angle = rng.uniform(-2.5, 2.5, t)
        frames[:, col] = angle
        rot[:, skel.index(name)] = Rotation.from_rotvec(np.outer(angle, [0, 0, 1])).as_matrix()
    return {"Loop": "none", "Frames": frames.tolist()}, rot, root


def test_known_rotations_give_their_joint_positions(tmp_path):
    doc, rot, root = _known_clip()
    path = tmp_path / "known.txt"
    path.write_text(json.dumps(doc))
    m = read_deepmimic(path)
    expect = forward_kinematics(deepmimic_skeleton(), rot, root)[0]
    assert m.num_frames == 12 and m.fps == 30.0
    np.testing.assert_allclose(m.joint_positions(), expect, atol=1e-5)


def test_uneven_keyframes_are_resampled_at_their_median_rate(tmp_path):
    """Keyframes 1/30 s apart but for one 2/30 s gap: resampled at 30 fps over the same span,
    the frame inside the gap halfway between its keyframes (hinges linearly, balls by slerp)."""
    doc, rot, root = _known_clip(t=6)
    doc["Frames"][2][0] = 2.0 / 30.0
    path = tmp_path / "uneven.txt"
    path.write_text(json.dumps(doc))
    m = read_deepmimic(path)
    assert m.num_frames == 7 and m.fps == 30.0 and m.meta["uneven_keyframes_resampled"]
    np.testing.assert_allclose(m.root_positions[3], 0.5 * (root[2] + root[3]), atol=1e-6)
    np.testing.assert_allclose(
        m.root_positions[[0, 1, 2, 4, 5, 6]], root[[0, 1, 2, 3, 4, 5]], atol=1e-6
    )
    knee = deepmimic_skeleton().index("RightLeg")
    angle = [Rotation.from_matrix(rot[i, knee]).as_rotvec()[2] for i in (2, 3)]
    got = Rotation.from_matrix(m.rotations[3, knee].astype(np.float64)).as_rotvec()
    np.testing.assert_allclose(got, [0.0, 0.0, np.mean(angle)], atol=1e-5)
    chest = deepmimic_skeleton().index("Chest")
    half = Rotation.from_matrix(rot[[2, 3], chest])
    mid = half[0] * Rotation.from_rotvec(0.5 * (half[0].inv() * half[1]).as_rotvec())
    np.testing.assert_allclose(m.rotations[3, chest], mid.as_matrix(), atol=1e-5)


def test_real_walk_is_a_walk(deepmimic_dir):
    """pybullet's walk: 30 fps, mapped onto the canonical joints, a 1.6 m person walking forward
    at about 1 m/s with the knees bent forwards and the feet at the floor (so the quaternion
    order, the hinges' axis and sign and the skeleton's offsets are DeepMimic's)."""
    m = load_motion(deepmimic_dir / "humanoid3d_walk.txt")
    assert (m.num_frames, m.fps, m.meta["unit"], m.meta["up_axis"]) == (39, 30.0, "m", "y")
    assert 1.55 < m.meta["standing_height_m"] < 1.7
    p = canonical_positions(m)  # (T, 20, 3) in MAPPED_JOINTS order
    idx = {n: i for i, n in enumerate(MAPPED_JOINTS)}
    left = p[:, idx["LeftUpLeg"]] - p[:, idx["RightUpLeg"]]
    forward = np.cross(left, [0.0, 1.0, 0.0])  # the studio's convention: left x up = forward
    forward /= np.linalg.norm(forward, axis=1, keepdims=True)
    speed = (np.gradient(p[:, 0], axis=0) * m.fps * forward).sum(1)
    assert 0.8 < speed.mean() < 1.3
    for side in ("Left", "Right"):
        mid = 0.5 * (p[:, idx[f"{side}UpLeg"]] + p[:, idx[f"{side}Foot"]])
        assert ((p[:, idx[f"{side}Leg"]] - mid) * forward).sum(1).min() > 0.0  # knees forward
    ankles = p[:, [idx["LeftFoot"], idx["RightFoot"]], 1]
    assert 0.03 < ankles.min() < 0.08


@pytest.mark.parametrize("clip", ["walk", "run", "spin", "dance_a"])
def test_a_loop_played_again_continues_where_it_ended(deepmimic_dir, clip):
    one = read_deepmimic(deepmimic_dir / f"humanoid3d_{clip}.txt")
    three = read_deepmimic(deepmimic_dir / f"humanoid3d_{clip}.txt", repeat=3)
    t = one.num_frames
    assert three.num_frames == 3 * (t - 1) + 1 and three.meta["repeat"] == 3
    np.testing.assert_allclose(three.joint_positions()[:t], one.joint_positions(), atol=1e-6)
    step = np.linalg.norm(np.diff(three.joint_positions(), axis=0), axis=2).max(1)
    inside = np.linalg.norm(np.diff(one.joint_positions(), axis=0), axis=2).max(1).max()
    assert step.max() < 1.25 * inside  # no jump at the seams
    heights = three.root_positions[:, 1]
    np.testing.assert_allclose(heights[t - 1 : 2 * t - 1], one.root_positions[:, 1], atol=1e-6)


def test_every_real_clip_reads(deepmimic_dir):
    clips = sorted(deepmimic_dir.glob("humanoid3d_*.txt"))
    assert len(clips) >= 10
    for path in clips:
        m = load_motion(path)
        assert m.num_frames >= 2 and np.isfinite(m.joint_positions()).all(), path


def _frames(n: int = 3) -> list[list[float]]:
    """n keyframes of the rest pose at 30 fps, the pelvis 0.9 m up."""
    identity = [1.0, 0.0, 0.0, 0.0]
    leg_and_arm = [*identity, 0.0, *identity, *identity, 0.0]  # hip, knee, ankle, shoulder, elbow
    row = [1 / 30, 0.0, 0.9, 0.0, *identity * 3, *leg_and_arm * 2]
    assert len(row) == FRAME_SIZE
    return [list(row) for _ in range(n)]


def _bad(kind: str) -> str | bytes:
    frames = _frames()
    if kind == "not_json":
        return "HIERARCHY\nROOT Hips\n"
    if kind == "binary":
        return b"\xff\xfe\x00garbage"
    if kind == "no_frames":
        return json.dumps({"Loop": "none"})
    if kind == "a_list":
        return json.dumps(frames)
    if kind == "short_row":
        frames[1] = frames[1][:40]
        return json.dumps({"Frames": frames})
    if kind == "one_frame":
        return json.dumps({"Frames": frames[:1]})
    if kind == "nan":
        return json.dumps({"Frames": frames}).replace("0.9", "NaN", 1)
    if kind == "text_value":
        frames[2][5] = "x"
        return json.dumps({"Frames": frames})
    if kind == "zero_quaternion":
        frames[1][8:12] = [0, 0, 0, 0]
        return json.dumps({"Frames": frames})
    if kind == "zero_duration":
        frames[0][0] = 0.0
        return json.dumps({"Frames": frames})
    if kind == "bad_loop":
        return json.dumps({"Loop": "forever", "Frames": frames})
    return ""


BAD = {
    "missing": "no such file",
    "empty": "empty file",
    "not_json": "not a DeepMimic motion",
    "binary": "not a DeepMimic motion",
    "no_frames": "no 'Frames' list",
    "a_list": "no 'Frames' list",
    "short_row": "keyframe 1 has 40 values",
    "one_frame": "at least 2 are needed",
    "nan": "keyframe 0 has a non-finite value",
    "text_value": "not a number",
    "zero_quaternion": "zero-length rotation of Chest",
    "zero_duration": "duration is not positive",
    "bad_loop": "unknown 'Loop'",
}


@pytest.mark.parametrize("kind", sorted(BAD))
@pytest.mark.parametrize("action", ["info", "retarget"])
def test_bad_input_exit_2_one_line_nothing_written(dng, tmp_path, kind, action):
    content = _bad(kind) if kind != "missing" else None
    path = tmp_path / f"{kind}.txt"
    assert_motion_file_refused(dng, tmp_path, path, content, action, BAD[kind])


def test_repeat_only_for_a_looping_clip(tmp_path, deepmimic_dir, bvh_dir):
    with pytest.raises(InputError, match="does not loop"):
        read_deepmimic(deepmimic_dir / "humanoid3d_kick.txt", repeat=2)
    with pytest.raises(InputError, match="only a looping DeepMimic clip"):
        load_motion(bvh_dir / "01_01.bvh", repeat=2)
    with pytest.raises(InputError, match="whole number >= 1"):
        read_deepmimic(deepmimic_dir / "humanoid3d_walk.txt", repeat=0)


def test_cli_info_and_retarget(dng, tmp_path, deepmimic_dir):
    walk = deepmimic_dir / "humanoid3d_walk.txt"
    code, out, err = dng("motion", "info", walk, "--repeat", "3", "--json")
    assert code == 0 and not err
    info = json.loads(out)
    assert info["frames"] == 115 and info["deepmimic"] == {"loop": "wrap", "repeat": 3}
    assert info["joints"]["RightForeArm"] == "RightForeArm"
    code, out, err = dng("motion", "info", walk)
    assert code == 0 and "DeepMimic humanoid, loop wrap" in out
    bvh = tmp_path / "walk.bvh"
    code, out, err = dng("motion", "retarget", walk, "--repeat", "2", "--out", bvh)
    assert code == 0 and not err
    back = load_motion(bvh)
    assert back.num_frames == 77 and back.fps == 30.0


def test_skeleton_table_matches_its_parents():
    skel = deepmimic_skeleton()
    assert skel.names[0] == "Hips" and len(DEEPMIMIC_JOINTS) == skel.num_joints == 16
    lengths = skel.bone_lengths()
    assert (lengths[1:] > 0.08).all()
