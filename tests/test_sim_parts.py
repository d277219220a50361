"""Simulation building blocks without the solver: config, colliders, pins, body drive, metrics."""

from __future__ import annotations

import numpy as np
import pytest

from core.body.colliders import body_capsules, capsule_distance, pose_capsules
from core.body.shape import BodyShape, mannequin_skeleton
from core.errors import InputError
from core.mesh import boundary_loops, unique_edges
from core.sim.config import FABRICS, SimConfig
from core.sim.drive import body_drive
from core.sim.pins import find_pins
from core.sim.simulate import edge_strain
from core.skeleton import forward_kinematics, skinning_transforms
from tests.conftest import assert_close
from tests.sim_helpers import frustum_skirt, spin_motion


def test_config_presets_and_validation():
    assert set(FABRICS) == {"silk", "cotton", "denim"}
    dens = [FABRICS[n].density for n in ("silk", "cotton", "denim")]
    assert dens == sorted(dens)
    with pytest.raises(InputError, match="unknown fabric"):
        SimConfig(fabric="tweed")
    with pytest.raises(InputError, match="substeps"):
        SimConfig(substeps=0)
    with pytest.raises(InputError, match="unknown solver"):
        SimConfig(solver="magic")
    c = SimConfig(substeps=4)
    assert (c.steps_per_frame(30), c.steps_per_frame(24), c.steps_per_frame(120)) == (4, 5, 1)
    assert c.as_dict()["fabric_params"]["name"] == "cotton"


def test_capsule_distance_matches_brute_force(rng):
    ends = rng.standard_normal((5, 2, 3))
    radii = rng.uniform(0.05, 0.3, 5)
    pts = rng.standard_normal((200, 3))
    got = capsule_distance(pts, ends, radii)
    # Brute force: sample each segment densely.
    s = np.linspace(0, 1, 2001)
    segs = ends[:, 0, None] + s[None, :, None] * (ends[:, 1] - ends[:, 0])[:, None]  # (K, S, 3)
    d = np.linalg.norm(pts[:, None, None] - segs[None], axis=-1).min(axis=2) - radii
    assert_close(got, d.min(axis=1), atol=2e-3, what="signed distance")


def test_capsules_cover_the_hips_and_follow_the_bones():
    shape = BodyShape()
    sk = mannequin_skeleton(shape)
    caps = body_capsules(sk, shape)
    rest = sk.rest_positions()
    # Hip joints and spine joints are inside the body.
    inside = capsule_distance(rest[[0, 1, 2, 3]], caps.endpoints, caps.radii)
    assert (inside < -0.05).all()
    # The hip girth at hip height is about the requested one (stadium sections).
    k = [i for i, n in enumerate(caps.names) if n.startswith("torso-0.495")]
    assert k, caps.names
    (a, b), r = caps.endpoints[k[0]], caps.radii[k[0]]
    girth = 2 * np.linalg.norm(b - a) + 2 * np.pi * r
    assert girth == pytest.approx(shape.hip, rel=0.05)
    # Rest transforms leave the capsules where they are; a turn moves them rigidly.
    m = spin_motion(10, turns_per_s=1.0)
    pos, rot = forward_kinematics(sk, m.rotations, m.root_positions)
    posed = pose_capsules(caps, skinning_transforms(sk, pos, rot))
    assert_close(posed[0], caps.endpoints, atol=1e-5, what="frame 0 (rest)")
    length = np.linalg.norm(posed[:, :, 1] - posed[:, :, 0], axis=-1)
    assert_close(length, np.broadcast_to(length[0], length.shape), atol=1e-5, what="lengths")


def test_pins_take_the_waist_loop_and_the_spine():
    shape = BodyShape()
    sk = mannequin_skeleton(shape)
    skirt = frustum_skirt(24, 12)
    loops = boundary_loops(skirt.faces)
    assert sorted(len(lp) for lp in loops) == [24, 24]
    pins = find_pins(skirt.vertices, skirt.faces, sk, 0.03, shape.height)
    top_y = skirt.vertices[:, 1].max()
    assert (skirt.vertices[pins.indices, 1] > top_y - 0.031).all()
    assert len(pins.indices) >= 24  # the whole top loop at least
    # One rigid band: every pinned vertex follows the same bone.
    assert len({sk.names[j] for j in pins.joints}) == 1
    assert sk.names[pins.joints[0]] in {"Hips", "Spine", "Spine1"}
    assert_close(pins.targets(np.eye(4)[None].repeat(sk.num_joints, 0)), pins.rest, what="rest")
    # A closed mesh has nothing to hang from.
    import trimesh

    box = trimesh.creation.box()
    with pytest.raises(InputError, match="no open boundary"):
        find_pins(box.vertices, box.faces, sk, 0.03, shape.height, path="box.obj")


def test_drive_blends_from_rest_and_hits_every_frame():
    shape = BodyShape()
    sk = mannequin_skeleton(shape)
    m = spin_motion(5, fps=30.0)
    m = type(m)(m.skeleton, m.rotations, m.root_positions + np.float32([0.1, 0, 0]), m.fps)
    d = body_drive(sk, m.rotations, m.root_positions, m.fps, 3, 0.5, 0.2)
    assert d.steps_per_frame == 3 and d.dt == pytest.approx(1 / 90)
    assert d.preroll_steps == 45 + 18
    assert d.num_steps == d.preroll_steps + 4 * 3
    rest = np.broadcast_to(np.eye(4, dtype=np.float32), d.transforms[0].shape)
    assert_close(d.transforms[0], rest, atol=1e-6, what="step 0 is the rest pose")
    pos, rot = forward_kinematics(sk, m.rotations, m.root_positions)
    want = skinning_transforms(sk, pos, rot)
    got = d.transforms[[d.frame_step(f) for f in range(5)]]
    assert_close(got, want, atol=1e-5, what="clip frames")
    # The lead-in is smooth: no step moves the root by more than a few mm.
    root = d.transforms[: d.preroll_steps + 1, 0, :3, 3]
    assert np.linalg.norm(np.diff(root, axis=0), axis=1).max() < 0.005


def test_edge_strain():
    skirt = frustum_skirt(12, 4)
    e = unique_edges(skirt.faces)
    rest = np.linalg.norm(skirt.vertices[e[:, 1]] - skirt.vertices[e[:, 0]], axis=1)
    assert np.abs(edge_strain(skirt.vertices, e, rest)).max() < 1e-6
    assert_close(edge_strain(1.1 * skirt.vertices, e, rest), np.full(len(e), 0.1), atol=1e-5)
    assert_close(edge_strain(0.5 * skirt.vertices, e, rest), np.full(len(e), -0.5), atol=1e-5)


def test_importing_the_sim_stage_stays_light():
    import subprocess
    import sys

    code = (
        "import sys, core.sim, core.sim.simulate, core.sim.preview, app.commands.simulate;"
        "print(sorted(m for m in ('newton', 'warp', 'matplotlib') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
