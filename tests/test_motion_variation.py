"""Training-library variations of a clip: speed, amplitude, heading."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.errors import InputError
from core.motion.procedural import make_motion
from core.motion.variation import source_frames, vary_motion
from pipeline.config import PRESETS, MotionSpec
from pipeline.stages.motions import motion_from_spec


@pytest.fixture(scope="module")
def dance():
    return make_motion("dance", 61, 30.0, 3)


def test_speed_plays_the_clip_faster_at_the_same_fps(dance):
    fast = vary_motion(dance, speed=2.0)
    assert fast.fps == dance.fps and fast.num_frames == 31
    # Frame k of the fast clip is frame 2k of the clip.
    np.testing.assert_allclose(fast.root_positions, dance.root_positions[::2], atol=1e-5)
    np.testing.assert_allclose(fast.rotations, dance.rotations[::2], atol=1e-5)
    assert source_frames(31, 2.0) == 61 and source_frames(10, 1.0) == 10


def test_amplitude_scales_joint_angles_and_keeps_the_root(dance):
    assert vary_motion(dance, amplitude=1.0).rotations.tobytes() == dance.rotations.tobytes()
    calm = vary_motion(dance, amplitude=0.0)
    np.testing.assert_allclose(
        calm.rotations[:, 1:], np.broadcast_to(np.eye(3), calm.rotations[:, 1:].shape), atol=1e-6
    )
    np.testing.assert_array_equal(calm.rotations[:, 0], dance.rotations[:, 0])
    half = vary_motion(dance, amplitude=0.5)

    def angle(r):
        return Rotation.from_matrix(np.asarray(r, np.float64).reshape(-1, 3, 3)).magnitude()

    np.testing.assert_allclose(
        angle(half.rotations[:, 1:]), 0.5 * angle(dance.rotations[:, 1:]), atol=1e-5
    )


def test_heading_turns_the_root_path_and_rotation(dance):
    turned = vary_motion(dance, heading_deg=90.0)
    p, q = dance.root_positions, turned.root_positions
    np.testing.assert_allclose(q[:, 1], p[:, 1], atol=1e-6)
    np.testing.assert_allclose(q[:, 0], p[:, 2], atol=1e-5)  # +90 deg about Y: x' = z
    np.testing.assert_allclose(q[:, 2], -p[:, 0], atol=1e-5)
    np.testing.assert_array_equal(turned.rotations[:, 1:], dance.rotations[:, 1:])


def test_bad_variations_are_refused(dance):
    for kwargs in ({"speed": 0.0}, {"amplitude": -1.0}, {"heading_deg": float("nan")}):
        with pytest.raises(InputError):
            vary_motion(dance, **kwargs)


def test_motion_specs_with_variations_keep_their_frame_count(bvh_dir):
    config = PRESETS["smoke"]
    spec = MotionSpec("v", "walk", 25, seed=2, speed=1.4, amplitude=1.2, heading_deg=30.0)
    assert motion_from_spec(spec, config).num_frames == 25
    spec = MotionSpec("c", "file", 20, path=str(bvh_dir / "01_03.bvh"), start_s=3.0, speed=0.8)
    assert motion_from_spec(spec, config).num_frames == 20


def test_turn_spins_the_body_and_keeps_its_speed(dance):
    idle = make_motion("idle", 31, 30.0, 1)
    spun = vary_motion(idle, turn_deg_s=180.0)  # half a turn a second: 90 degrees at frame 15
    p, q = idle.root_positions, spun.root_positions
    np.testing.assert_allclose(q[0], p[0], atol=1e-6)
    np.testing.assert_allclose(q[:, 1], p[:, 1], atol=1e-6)
    # The body's facing (the root's local +Z) turns by the angle.
    facing = lambda m: m.rotations[:, 0] @ np.array([0.0, 0.0, 1.0], np.float32)  # noqa: E731
    a, b = facing(idle)[30], facing(spun)[30]  # a full half turn at frame 30
    np.testing.assert_allclose(b[[0, 2]], -a[[0, 2]], atol=1e-5)
    # Each step of the root turns with the body: the same length, turned by the frame's angle.
    walk = make_motion("walk", 31, 30.0, 2)
    curl = vary_motion(walk, turn_deg_s=90.0)
    d, e = np.diff(walk.root_positions, axis=0), np.diff(curl.root_positions, axis=0)
    np.testing.assert_allclose(np.linalg.norm(e, axis=1), np.linalg.norm(d, axis=1), atol=1e-5)
    np.testing.assert_allclose(e[29, [0, 2]], [d[29, 2], -d[29, 0]], atol=1e-5)  # 90 deg at 30
