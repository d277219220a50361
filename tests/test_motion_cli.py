"""``dng motion``: info on real and converted files, bad input, make and retarget."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from core.motion.bvh import write_bvh
from core.motion.load import load_motion
from core.motion.procedural import PROCEDURAL_KINDS
from core.skeleton import CANONICAL_JOINTS
from tests.conftest import assert_motion_file_refused
from tests.data_bvh import cmu_as, tiny_bvh_text


@pytest.fixture(scope="module")
def converted(bvh_dir, tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("cli_other_tools")
    files = {}
    for style in ("biped", "mixamo", "rigify"):
        files[style] = out / f"{style}.bvh"
        cmu_as(style, bvh_dir / "01_01.bvh", files[style], slice(0, 120))
    return files


@pytest.fixture(scope="module")
def cmu_short(bvh_dir, tmp_path_factory) -> Path:
    """The first 2 s of CMU 01_01, written in metres (keeps the retarget tests quick)."""
    m = load_motion(bvh_dir / "01_01.bvh")
    m = replace(m, rotations=m.rotations[:240], root_positions=m.root_positions[:240])
    path = tmp_path_factory.mktemp("cmu_short") / "01_01_short.bvh"
    write_bvh(path, m)
    return path


def test_info_text(dng, bvh_dir):
    code, out, err = dng("motion", "info", bvh_dir / "01_01.bvh")
    assert code == 0 and not err
    assert "2752 at 120 fps" in out
    assert "standing height: 1.4" in out or "standing height: 1.5" in out
    assert "up axis:         Y" in out and "unit:            cmu" in out
    for c in CANONICAL_JOINTS:
        assert f"\n  {c} " in out or f"\n  {c}<" in out
    assert "LeftForeArm   <- LeftForeArm" in out


def test_info_json_cmu(dng, bvh_dir):
    code, out, _ = dng("motion", "info", bvh_dir / "01_01.bvh", "--json")
    assert code == 0
    info = json.loads(out)
    assert info["frames"] == 2752 and info["fps"] == 120.0
    assert info["duration_s"] == pytest.approx(2751 / 120)
    assert list(info["joints"]) == list(CANONICAL_JOINTS)
    assert info["up_axis"] == "y" and info["unit"] == "cmu"
    assert 1.45 < info["standing_height_m"] < 1.9
    assert info["root_path_length_m"] >= info["root_displacement_m"] > 0
    assert len(info["source_joints"]) == 31


@pytest.mark.parametrize(
    "style, up, unit", [("biped", "z", "estimated"), ("mixamo", "y", "cm"), ("rigify", "y", "m")]
)
def test_info_json_other_tools(dng, converted, bvh_dir, style, up, unit):
    code, out, _ = dng("motion", "info", converted[style], "--json")
    assert code == 0
    info = json.loads(out)
    assert len(info["joints"]) == 19 and set(info["joints"]) == set(CANONICAL_JOINTS)
    assert info["up_axis"] == up and info["unit"] == unit and info["rig"] == style
    _, ref_out, _ = dng("motion", "info", bvh_dir / "01_01.bvh", "--json")
    true_height = json.loads(ref_out)["standing_height_m"]
    if unit != "estimated":
        assert info["standing_height_m"] == pytest.approx(true_height, rel=0.10)


def test_info_scale_and_mapping_options(dng, converted, tmp_path):
    text = converted["rigify"].read_text().replace("JOINT DEF-forearm.L\n", "JOINT Bone08\n")
    odd = tmp_path / "odd.bvh"
    odd.write_text(text)
    code, _, err = dng("motion", "info", odd)
    assert code == 2 and "LeftForeArm" in err and str(odd) in err
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps({"LeftForeArm": "Bone08"}))
    code, out, _ = dng("motion", "info", odd, "--json", "--mapping", mapping, "--scale", "0.5")
    assert code == 0
    info = json.loads(out)
    assert info["joints"]["LeftForeArm"] == "Bone08" and info["unit_scale"] == 0.5


# ------------------------------------------------------------------------------ bad input

_TINY = tiny_bvh_text(frames=3)


def _break(kind: str) -> str | bytes | None:
    lines = _TINY.splitlines()
    if kind == "empty":
        return ""
    if kind == "truncated":
        return "\n".join(lines[:-1]) + "\n"  # Frames: 3, two lines
    if kind == "cut_mid_hierarchy":
        return "\n".join(lines[:9]) + "\n"
    if kind == "zero_frames":
        return _TINY.replace("Frames: 3", "Frames: 0")
    if kind == "nan":
        return _TINY.replace("2.0 90 0 4.0", "2.0 90 0 nan")
    if kind == "short_line":
        return "\n".join(lines[:-1] + [lines[-1].rsplit(" ", 1)[0]]) + "\n"
    if kind == "long_line":
        return "\n".join(lines[:-1] + [lines[-1] + " 7"]) + "\n"
    if kind == "bad_channel":
        return _TINY.replace(
            "Zrotation Xrotation Yrotation\n\t\tEnd", "Zrotation Xrot Yrotation\n\t\tEnd"
        )
    if kind == "channel_count":
        return _TINY.replace("CHANNELS 3", "CHANNELS 4")
    if kind == "missing_brace":
        return _TINY.replace("\t}\n}\nMOTION", "\t}\nMOTION")
    if kind == "extra_brace":
        return _TINY.replace("\t}\n}\nMOTION", "\t}\n}\n}\nMOTION")
    if kind == "not_a_number":
        return _TINY.replace("OFFSET 0 20 0", "OFFSET 0 twenty 0")
    if kind == "garbage":
        return b"\x89PNG\r\n\x1a\n\x00\x00 not a bvh"
    if kind == "unknown_rig":
        return _TINY
    raise AssertionError(kind)


BAD = {
    "missing": "no such file",
    "empty": "empty file",
    "truncated": "truncated",
    "cut_mid_hierarchy": "unbalanced braces",
    "zero_frames": "no frames",
    "nan": "not finite",
    "short_line": "has 8 values",
    "long_line": "has 10 values",
    "bad_channel": "unknown channel name 'Xrot'",
    "channel_count": "CHANNELS says 4",
    "missing_brace": "unbalanced braces",
    "extra_brace": "unbalanced braces",
    "not_a_number": "not a number",
    "garbage": "not a BVH file",
    "unknown_rig": "LeftArm",
}


@pytest.mark.parametrize("kind", sorted(BAD))
@pytest.mark.parametrize("action", ["info", "retarget"])
def test_bad_input_exit_2_one_line_nothing_written(dng, tmp_path, kind, action):
    content = _break(kind) if kind != "missing" else None
    path = tmp_path / f"{kind}.bvh"
    assert_motion_file_refused(dng, tmp_path, path, content, action, BAD[kind])


def test_line_numbers_in_messages(dng, tmp_path):
    path = tmp_path / "nan.bvh"
    path.write_text(_break("nan"))
    _, _, err = dng("motion", "info", path)
    assert f"line {_TINY.splitlines().index('2.0 90 0 4.0 0 0 0 6.0 0') + 1}:" in err


def test_unknown_rig_lists_every_missing_joint(dng, tmp_path):
    path = tmp_path / "stick.bvh"
    path.write_text(_TINY)
    _, _, err = dng("motion", "info", path)
    for c in ("Head", "LeftArm", "RightForeArm", "LeftHand", "LeftUpLeg", "RightFoot"):
        assert c in err


# ------------------------------------------------------------------------- make, retarget


def test_make_writes_a_loadable_clip(dng, tmp_path):
    kind = PROCEDURAL_KINDS[0]
    a, b = tmp_path / "a.bvh", tmp_path / "b.bvh"
    for out in (a, b):
        code, _, err = dng("motion", "make", kind, "--frames", 40, "--fps", 25, "--seed", 3,
                           "--out", out, "--shape", "height=1.8")  # fmt: skip
        assert code == 0, err
    assert a.read_bytes() == b.read_bytes()  # same seed, same file
    m = load_motion(a)
    assert m.num_frames == 40 and m.fps == 25.0
    assert m.meta["unit"] == "m" and m.meta["up_axis"] == "y"
    assert m.meta["standing_height_m"] == pytest.approx(1.8, rel=0.05)


@pytest.mark.parametrize(
    "argv, problem",
    [
        (["no_such_kind", "--frames", "10"], "unknown motion kind"),
        (["KIND", "--frames", "0"], "--frames"),
        (["KIND", "--frames", "10", "--shape", "height=9"], "height"),
    ],
)
def test_make_bad_arguments(dng, tmp_path, argv, problem):
    argv = [PROCEDURAL_KINDS[0] if a == "KIND" else a for a in argv]
    out = tmp_path / "m.bvh"
    code, _, err = dng("motion", "make", *argv, "--out", out)
    assert code == 2 and problem in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_retarget_cmu_onto_the_mannequin(dng, tmp_path, cmu_short):
    out = tmp_path / "r.bvh"
    code, stdout, err = dng("motion", "retarget", cmu_short, "--out", out, "--fps", 30,
                            "--shape", "height=1.8")  # fmt: skip
    assert code == 0, err
    m = load_motion(out)
    assert m.fps == 30.0 and m.num_frames == round(239 * 30 / 120) + 1
    assert m.meta["rig"] == "canonical"
    assert m.meta["standing_height_m"] == pytest.approx(1.8, rel=0.05)
    assert "wrote" in stdout


def test_retarget_z_up_biped_lands_upright(dng, tmp_path, converted):
    out = tmp_path / "r.bvh"
    code, _, err = dng("motion", "retarget", converted["biped"], "--out", out)
    assert code == 0, err
    m = load_motion(out)
    pos = m.joint_positions()
    head, hips = m.skeleton.index("Head"), m.skeleton.index("Hips")
    assert (pos[:, head, 1] > pos[:, hips, 1] + 0.3).all()  # Y up after conversion
