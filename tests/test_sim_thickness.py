"""A layered garment's proxy is kept off the body by the depth of the layers beneath it: the
depth measured (core.sim.thickness), capped at the room the proxy has at rest, and honoured by
the simulation's contacts."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.body.colliders import capsule_distance, pose_capsules
from core.body.shape import BodyShape
from core.errors import InputError
from core.sim.config import SimConfig
from core.sim.simulate import contact_thickness, prepare, simulate
from core.sim.thickness import layer_thickness
from tests.sim_helpers import frustum_skirt, spin_motion

FAST = SimConfig(substeps=2, iterations=4, transition_s=0.2, settle_s=0.2)


def _shrunk(vertices: np.ndarray, by: float) -> np.ndarray:
    """The skirt moved ``by`` metres towards its vertical axis (a layer inside it)."""
    v = np.array(vertices, np.float64)
    r = np.linalg.norm(v[:, [0, 2]], axis=1, keepdims=True)
    v[:, [0, 2]] *= (r - by) / r
    return v


def test_the_depth_of_an_inner_layer_is_measured_along_the_normal():
    proxy = frustum_skirt(24, 12)
    inner = _shrunk(proxy.vertices, 0.03)
    target = np.concatenate([proxy.vertices, inner])  # the outer layer and one 30 mm inside
    t = layer_thickness(proxy.vertices, proxy.faces, target)
    assert t.shape == (proxy.num_vertices,)
    # 30 mm radially on a cone that opens downwards: a little less along its normal
    assert 0.025 < t.min() <= t.max() < 0.0305
    # a layer outside the proxy is not beneath it
    outside = layer_thickness(proxy.vertices, proxy.faces, _shrunk(proxy.vertices, -0.03))
    assert outside.max() == 0.0


def test_bad_input_names_the_file():
    proxy = frustum_skirt(12, 6)
    bad = np.array(proxy.vertices, np.float64)
    bad[3] = np.nan
    with pytest.raises(InputError, match="target.obj"):
        layer_thickness(proxy.vertices, proxy.faces, bad, "target.obj")
    with pytest.raises(InputError, match="proxy"):
        layer_thickness(proxy.vertices[:, :2], proxy.faces, proxy.vertices)
    with pytest.raises(InputError, match=r"\(V,\)"):
        prepare(proxy, spin_motion(3), BodyShape(), FAST, thickness=np.zeros(5))


def test_thickness_is_capped_at_the_room_at_rest():
    skirt = frustum_skirt(24, 12, hem_radius=0.22)
    run = prepare(skirt, spin_motion(3), BodyShape(), FAST)
    capped = contact_thickness(skirt, run.capsules, FAST, np.full(skirt.num_vertices, 1.0))
    room = capsule_distance(
        skirt.vertices.astype(np.float64), run.capsules.endpoints, run.capsules.radii
    )
    np.testing.assert_allclose(capped, np.maximum(room - FAST.collision_margin, 0.0))
    with pytest.raises(InputError, match="thickness"):
        contact_thickness(skirt, run.capsules, FAST, np.full(skirt.num_vertices, -0.01))


def test_the_simulation_keeps_each_vertex_off_the_body_by_its_thickness():
    skirt = frustum_skirt(24, 12, hem_radius=0.22)
    motion = spin_motion(6)
    layers = np.full(skirt.num_vertices, 0.03)
    run = prepare(skirt, motion, BodyShape(), FAST, thickness=layers)
    drive = run.drive
    ends = pose_capsules(run.capsules, drive.transforms[[drive.frame_step(f) for f in range(6)]])
    free = np.setdiff1d(np.arange(skirt.num_vertices), run.pins.indices)

    def room_left(positions: np.ndarray) -> float:
        """Least clearance beyond each free vertex's thickness over the clip (metres)."""
        clear = [
            capsule_distance(p[free].astype(np.float64), e, run.capsules.radii)
            for p, e in zip(positions, ends)
        ]
        return float((np.stack(clear) - run.thickness[free]).min())

    thick, report = simulate(skirt, motion, BodyShape(), FAST, thickness=layers)
    thin, _ = simulate(skirt, motion, BodyShape(), FAST)
    assert room_left(thin.positions) < -0.003  # without it the cloth comes closer
    assert room_left(thick.positions) >= 0.0
    assert thick.params["layer_thickness_mm"]["max"] == pytest.approx(30.0)
    assert thin.params["layer_thickness_mm"] is None
    assert any("kept off the body by the layers" in n for n in report.notes)


def test_cli_simulates_a_proxy_with_its_layers(tmp_path, capsys):
    from app.cli import main
    from core.mesh import Mesh, save_mesh
    from core.motion.bvh import write_bvh

    proxy = frustum_skirt(24, 12)
    inner = _shrunk(proxy.vertices, 0.03)
    faces = np.concatenate([proxy.faces, proxy.faces + proxy.num_vertices])
    target = Mesh(np.concatenate([proxy.vertices, inner]).astype(np.float32), faces)
    save_mesh(tmp_path / "proxy.obj", proxy)
    save_mesh(tmp_path / "target.obj", target)
    write_bvh(tmp_path / "spin.bvh", spin_motion(4))
    args = [
        "simulate", "--garment", str(tmp_path / "proxy.obj"), "--motion",
        str(tmp_path / "spin.bvh"), "--substeps", "2", "--iterations", "4", "--transition",
        "0.2", "--json", "--out", str(tmp_path / "c.npz"),
    ]  # fmt: skip
    assert main([*args, "--layers", str(tmp_path / "target.obj")]) == 0
    report = json.loads(capsys.readouterr().out)
    assert any("kept off the body by the layers beneath it" in n for n in report["notes"])
    assert main([*args, "--layers", str(tmp_path / "missing.obj")]) == 2
    assert "missing.obj" in capsys.readouterr().err
    embed = ["--embed-in", str(tmp_path / "proxy.obj"), str(tmp_path / "c.npz")]
    assert main([*args, "--layers", str(tmp_path / "target.obj"), *embed]) == 2
