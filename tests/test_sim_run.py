"""Short cloth simulations (newton on CPU): a settled start, determinism, blow-up handling, CLI.

The first run in a fresh environment compiles warp kernels (a minute or two, then cached).
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from core.body.shape import BodyShape
from core.mesh import unique_edges
from core.motion.motion import Motion
from core.sim.cache import load_cache
from core.sim.config import CHEBYSHEV_RHO, SimConfig
from core.sim.simulate import SimulationError, edge_strain, simulate
from core.skeleton import rotation_about
from tests.sim_helpers import frustum_skirt, spin_motion

#: Fast settings for tests: short lead-in, few steps.
FAST = SimConfig(substeps=2, iterations=4, transition_s=0.2, settle_s=0.2)


@pytest.fixture(scope="module")
def skirt():
    return frustum_skirt(24, 12)


@pytest.fixture(scope="module")
def first_run(skirt):
    return simulate(skirt, spin_motion(6), BodyShape(), FAST)


def test_short_simulation_is_settled_and_sane(skirt, first_run):
    cache, report = first_run
    assert cache.positions.shape == (6, skirt.num_vertices, 3)
    assert cache.positions.dtype == np.float32 and report.finite
    assert np.isfinite(cache.positions).all()
    # Gravity pulled the hem down a little, the waistband stayed on the body.
    assert cache.positions[0, :, 1].min() < skirt.vertices[:, 1].min()
    e = unique_edges(skirt.faces)
    rest = np.linalg.norm(skirt.vertices[e[:, 1]] - skirt.vertices[e[:, 0]], axis=1)
    strain = edge_strain(cache.positions, e, rest)
    assert report.strain_max == pytest.approx(float(strain.max()), rel=1e-5)
    assert report.compression_max == pytest.approx(float(-strain.min()), rel=1e-5)
    assert report.strain_max < report.strain_limit
    assert report.penetration_mean_mm < 2.0
    from core.sim.sanity import hem_indices, hem_radius, hem_radius_ratio

    hem, waist = hem_indices(skirt.vertices, skirt.faces), np.array(cache.params["pinned_indices"])
    dressed = hem_radius(skirt.vertices[None].astype(np.float64), hem, waist)[0]  # not frame 0's
    ratio = hem_radius_ratio(cache.positions, hem, waist, reference=dressed)
    assert report.hem_radius_ratio == pytest.approx(ratio)
    assert report.frames == 6 and report.steps_per_frame == 2
    assert report.ms_per_frame > 0 and report.pinned >= 24
    assert cache.params["sim"]["fabric"] == "cotton" and cache.params["steps_per_frame"] == 2
    assert cache.params["solver"] == "newton.SolverStyle3D"  # the default, style3d


def test_same_inputs_give_the_same_cache(skirt, first_run):
    again, _ = simulate(skirt, spin_motion(6), BodyShape(), FAST)
    assert np.array_equal(again.positions, first_run[0].positions)


def test_spin_moves_the_skirt_with_the_body(first_run):
    cache, _ = first_run
    # The body turns 0.5 turn/s: the waistband (pinned) turns with it, about 6 degrees a frame.
    top = cache.positions[:, :24]
    ang = np.arctan2(top[:, :, 0], top[:, :, 2])
    turn = np.degrees(np.angle(np.exp(1j * (ang[-1] - ang[0]))).mean())
    assert turn == pytest.approx(5 * 6.0, abs=2.0)


def test_blow_up_is_detected_and_nothing_is_returned(skirt):
    # A speed limit no garment can keep: every retry fails and the run stops with a clear error.
    cfg = replace(FAST, max_speed=1e-4, max_retries=1)
    with pytest.raises(SimulationError, match=r"runaway speed .* 1 retries"):
        simulate(skirt, spin_motion(3), BodyShape(), cfg, path="skirt.obj")


def test_cli_simulate_writes_cache_report_and_refuses_garbage(tmp_path, skirt, capsys):
    from app.cli import main
    from core.mesh import save_mesh
    from core.motion.bvh import write_bvh

    save_mesh(tmp_path / "skirt.obj", skirt)
    write_bvh(tmp_path / "spin.bvh", spin_motion(4))
    args = [
        "simulate", "--garment", str(tmp_path / "skirt.obj"), "--motion", str(tmp_path / "spin.bvh"),
        "--substeps", "2", "--iterations", "4", "--transition", "0.2", "--chebyshev", "0.5",
        "--json", "--out", str(tmp_path / "c.npz"), "--export", str(tmp_path / "c.pc2"),
        "--preview", str(tmp_path / "p.png"),
    ]  # fmt: skip
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["finite"] and report["frames"] == 4
    assert (tmp_path / "p.png").stat().st_size > 0 and report["preview_frames"] == [0, 1, 2, 3]
    assert (tmp_path / "c.report.json").is_file()
    cache = load_cache(tmp_path / "c.npz")
    assert cache.positions.shape == (4, skirt.num_vertices, 3)
    assert cache.params["sim"]["chebyshev_rho"] == 0.5 and report["hem_radius_ratio"] > 0
    # Round trip through the PC2 export and the import path of the CLI.
    imp = ["simulate", "--import", str(tmp_path / "c.pc2"), "--garment", str(tmp_path / "skirt.obj"),
           "--out", str(tmp_path / "i.npz"), "--fps", "30"]  # fmt: skip
    assert main(imp) == 0
    assert np.array_equal(load_cache(tmp_path / "i.npz").positions, cache.positions)
    # A garment with another vertex count is refused, with the file named.
    save_mesh(tmp_path / "other.obj", frustum_skirt(20, 12))
    imp[4] = str(tmp_path / "other.obj")
    assert main(imp) == 2
    assert "topology mismatch" in capsys.readouterr().err
    # --set reaches any other setting; one with a flag of its own, or none, is refused.
    args[args.index("--chebyshev") : args.index("--chebyshev") + 2] = ["--set", "damping=0.5"]
    assert main(args) == 0
    assert load_cache(tmp_path / "c.npz").params["sim"]["damping"] == 0.5
    capsys.readouterr()
    for bad in ("substeps=3", "stiffness=2"):
        assert main([*args, "--set", bad]) == 2
        assert f"--set {bad.split('=')[0]}: not a simulation setting" in capsys.readouterr().err
    assert main([*args, "--set", "damping=fast"]) == 2  # a value of the wrong type, named
    assert "damping='fast' must be of type float" in capsys.readouterr().err


def test_frame_zero_is_settled_by_the_lead_in(skirt):
    # A clip that holds a pose far from the rest pose: turned 60 degrees, hips shifted 5 cm.
    m = spin_motion(3, turns_per_s=0.0)
    rot = m.rotations.copy()
    rot[:, 0] = rotation_about([0, 1, 0], np.radians(60.0))
    held = Motion(m.skeleton, rot, m.root_positions + np.float32([0.05, 0, 0]), m.fps)
    settled, _ = simulate(skirt, held, BodyShape(), replace(FAST, settle_s=0.6))
    moved = np.linalg.norm(settled.positions[2] - settled.positions[0], axis=1).max()
    # Without the lead-in the body jumps to the pose at once and the skirt is still swinging.
    cold, _ = simulate(
        skirt, held, BodyShape(), replace(FAST, transition_s=0.0, settle_s=0.0, max_speed=1e3)
    )
    swinging = np.linalg.norm(cold.positions[2] - cold.positions[0], axis=1).max()
    assert moved < 0.002 < swinging, (moved, swinging)


def test_layered_garment_turns_self_collision_on():
    from tests.sim_helpers import two_layer_skirt

    layered = two_layer_skirt()
    cache, report = simulate(layered, spin_motion(3), BodyShape(), FAST)
    assert cache.params["sim"]["self_collision"] is True
    assert report.finite and report.strain_max < report.strain_limit
    assert report.pinned >= 48  # both waistbands


def test_serial_pcg_solves_as_newtons(skirt, monkeypatch):
    # Each linear solve runs both ways on the same inputs: our one-launch PCG (CPU) and newton's
    # PcgSolver (five launches per iteration); the solutions agree to float rounding.
    import warp as wp

    from core.sim import simulate as sim_module

    serial = sim_module._Scene._serial_pcg
    worst = []

    def both(self):
        newtons = self.solver.linear_solver.solve
        serial(self)
        ours = self.solver.linear_solver.solve

        def solve(a_non_diag, a_diag, x0, b, inv_m, x1, iterations, additional=None):
            start = None if x0 is None else x0.numpy().copy()
            newtons(a_non_diag, a_diag, x0, b, inv_m, x1, iterations, additional)
            ref = x1.numpy().copy()
            if start is not None:
                x1.assign(wp.array(start, dtype=wp.vec3, device=x1.device))
            ours(a_non_diag, a_diag, x0, b, inv_m, x1, iterations, additional)
            scale = max(float(np.abs(ref).max()), 1e-9)
            worst.append(float(np.abs(x1.numpy() - ref).max()) / scale)

        self.solver.linear_solver.solve = solve

    monkeypatch.setattr(sim_module._Scene, "_serial_pcg", both)
    simulate(skirt, spin_motion(3), BodyShape(), FAST)
    assert len(worst) > 10 and max(worst) < 1e-4, max(worst)


def test_plain_iterations_are_newtons_step_bit_for_bit(skirt, monkeypatch):
    # chebyshev_rho = 0 (the plain iterations): core.sim.style3d's loop against newton's own
    # SolverStyle3D.step (its control argument is unused): the caches are identical.
    from core.sim.style3d import AcceleratedStep

    plain = replace(FAST, chebyshev_rho=0.0)
    ours, _ = simulate(skirt, spin_motion(6), BodyShape(), plain)
    accelerated, _ = simulate(skirt, spin_motion(6), BodyShape(), FAST)  # one surface: 0.99
    assert accelerated.params["sim"]["chebyshev_rho"] == CHEBYSHEV_RHO
    assert not np.array_equal(accelerated.positions, ours.positions)

    def newtons_step(self, state_in, state_out, contacts, dt):
        self.solver.step(state_in, state_out, None, contacts, dt)

    monkeypatch.setattr(AcceleratedStep, "__call__", newtons_step)
    theirs, _ = simulate(skirt, spin_motion(6), BodyShape(), plain)
    assert np.array_equal(theirs.positions, ours.positions)


def test_chebyshev_weights_and_a_spin_with_them():
    from core.sim.style3d import CHEBYSHEV_DELAY, chebyshev_omegas

    plain = chebyshev_omegas(0.0, 8)
    assert plain == [1.0] * 8
    w = chebyshev_omegas(0.9, 8)
    assert w[: CHEBYSHEV_DELAY + 1] == [1.0] * (CHEBYSHEV_DELAY + 1)
    assert w[CHEBYSHEV_DELAY + 1] == pytest.approx(2 / (2 - 0.81))
    assert all(1 < a < 2 for a in w[CHEBYSHEV_DELAY + 1 :])  # over-relaxation, below 2
    with pytest.raises(Exception, match="chebyshev_rho"):
        SimConfig(chebyshev_rho=1.0)
    cache, report = simulate(
        frustum_skirt(24, 12), spin_motion(6), BodyShape(), replace(FAST, chebyshev_rho=0.9)
    )
    assert np.isfinite(cache.positions).all() and report.strain_max < 0.2
    assert not report.retried_frames
