"""The source's floor under a retargeted capture: estimated from the height most frames' lower
ankle reaches, not from its minimum, so that a few frames with a foot dipped through the floor
neither lift the clip nor move the floor; they are reported."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from app.cli import main as dng
from core.body.shape import MANNEQUIN_JOINTS, BodyShape, mannequin_skeleton
from core.motion.bvh import write_bvh
from core.motion.load import load_motion
from core.motion.mapping import canonical_positions
from core.motion.procedural import make_motion
from core.motion.retarget import estimate_floor, frame_ranges, retarget
from core.skeleton import forward_kinematics

DIP_FRAMES = [100, 101, 102, 200]
DIP_M = 0.10


def _ankles(t: int, floor: float) -> np.ndarray:
    """(t, 2, 3): two ankles walking on ``floor``: each planted half the time, lifted 15 cm."""
    phase = np.linspace(0, 6 * np.pi, t)
    a = np.zeros((t, 2, 3))
    a[:, 0, 1] = floor + 0.15 * np.clip(np.sin(phase), 0, None)
    a[:, 1, 1] = floor + 0.15 * np.clip(-np.sin(phase), 0, None)
    a[:, :, 2] = np.where(a[:, :, 1] > floor + 1e-9, phase[:, None] * 0.1, 0.0)
    return a


def test_estimate_floor_ignores_a_few_dipped_frames_and_reports_them():
    clean = estimate_floor(_ankles(300, 0.08), 30.0, 0.85)
    assert clean.method == "support" and clean.height_m == pytest.approx(0.08, abs=1e-6)
    assert len(clean.below) == 0 and clean.deepest_m == 0.0 and len(clean.contacts) > 100
    dipped = _ankles(300, 0.08)
    dipped[DIP_FRAMES, 0, 1] = 0.08 - DIP_M
    found = estimate_floor(dipped, 30.0, 0.85)
    assert found.height_m == pytest.approx(0.08, abs=1e-6)  # the minimum would be -0.02
    assert list(found.below) == DIP_FRAMES
    assert found.deepest_m == pytest.approx(DIP_M, abs=1e-6)
    assert found.summary()["below_frames"] == DIP_FRAMES


def test_estimate_floor_none_given_and_ranges():
    a = _ankles(60, 0.08)
    assert estimate_floor(a, 30.0, 0.85, "none").height_m == 0.0
    given = estimate_floor(a, 30.0, 0.85, 0.2)
    assert given.method == "given" and given.height_m == 0.2 and len(given.below) > 0
    one = estimate_floor(a[:1], 30.0, 0.85)  # a single frame stands on its own ankle
    assert one.height_m == pytest.approx(0.08)
    assert frame_ranges(np.array([0, 1, 2, 5, 7, 8])) == [[0, 2], [5, 5], [7, 8]]
    assert frame_ranges(np.array([], np.int64)) == []


def _lowest_ankle(motion) -> np.ndarray:
    pos, _ = forward_kinematics(motion.skeleton, motion.rotations, motion.root_positions)
    idx = [MANNEQUIN_JOINTS.index(n) for n in ("LeftFoot", "RightFoot")]
    return pos[:, idx, 1].min(1)


@pytest.fixture(scope="module")
def dipped_capture(tmp_path_factory):
    """A walk on the floor written as BVH, and the same walk with the body dropped 10 cm
    through the floor in a few frames (a marker swap, a bad floor calibration)."""
    root = tmp_path_factory.mktemp("floor")
    walk = make_motion("walk", 300, 30.0, 0)
    clean, dipped = root / "walk.bvh", root / "walk-dipped.bvh"
    write_bvh(clean, walk)
    lowered = walk.root_positions.copy()
    lowered[DIP_FRAMES, 1] -= DIP_M
    write_bvh(dipped, replace(walk, root_positions=lowered))
    return clean, dipped


def test_a_dipped_capture_retargets_onto_the_floor_and_reports_the_dip(dipped_capture):
    clean, dipped = dipped_capture
    out = {}
    for path in (clean, dipped):
        m = load_motion(path)
        out[path] = retarget(canonical_positions(m), m.fps, name=path.stem)
    low_clean, low_dipped = _lowest_ankle(out[clean]), _lowest_ankle(out[dipped])
    rest = mannequin_skeleton(BodyShape()).rest_positions()
    ankle_rest = float(rest[MANNEQUIN_JOINTS.index("LeftFoot"), 1])
    keep = np.setdiff1d(np.arange(len(low_dipped)), DIP_FRAMES)
    # standing: the lowest ankle at the mannequin's standing ankle height, within 1 cm
    assert abs(np.percentile(low_dipped[keep], 5) - ankle_rest) < 0.01
    assert np.abs(low_dipped[keep] - low_clean[keep]).max() < 0.01
    floor = out[dipped].meta["floor"]
    assert floor["below_frames"] == DIP_FRAMES
    assert floor["below_deepest_m"] == pytest.approx(DIP_M, abs=0.01)
    assert out[clean].meta["floor"]["below_frames"] == []


def test_motion_info_and_retarget_report_the_floor(dipped_capture, tmp_path, capsys):
    _, dipped = dipped_capture
    assert dng(["motion", "info", str(dipped), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["floor"]["below_frames"] == DIP_FRAMES
    assert info["floor"]["contact_frames"] > 50
    assert dng(["motion", "info", str(dipped)]) == 0
    text = capsys.readouterr().out
    assert "floor:" in text and "4 frames with a foot below the floor" in text
    out = tmp_path / "out.bvh"
    assert dng(["motion", "retarget", str(dipped), "--out", str(out)]) == 0
    assert "below the floor" in capsys.readouterr().out and out.is_file()
    assert dng(["motion", "retarget", str(dipped), "--out", str(out), "--floor", "0.0"]) == 0
    for bad in ("low", "nan", "inf"):
        target = tmp_path / f"bad-{bad}.bvh"
        assert dng(["motion", "retarget", str(dipped), "--out", str(target), "--floor", bad]) == 2
        assert "--floor must be auto, none or a height" in capsys.readouterr().err
        assert not target.exists()
