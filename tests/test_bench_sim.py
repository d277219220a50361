"""``dng bench sim``: settings parsing, the distance figures, and a tiny run end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.bench.sim import distance_stats, format_table, settings_to_measure
from core.errors import InputError
from core.sim.config import QUALITY


def test_settings_and_distances():
    assert settings_to_measure("draft,final", "3,5") == [
        ("draft", QUALITY["draft"]),
        ("final", QUALITY["final"]),
        ("3x5", (3, 5)),
    ]
    with pytest.raises(InputError, match="unknown quality"):
        settings_to_measure("fast", "")
    with pytest.raises(InputError, match="S,I"):
        settings_to_measure("", "2,x")
    ref = np.zeros((2, 10, 3))
    pos = ref.copy()
    pos[:, :, 0] = np.linspace(0.001, 0.010, 10)  # 1..10 mm
    mean, p95 = distance_stats(pos, ref)
    assert mean == pytest.approx(5.5)
    assert p95 == pytest.approx(np.percentile(np.tile(np.arange(1.0, 11.0), 2), 95))


def test_tiny_bench_writes_table_json_and_plot(tmp_path, capsys):
    from app.cli import main
    from core.mesh import save_mesh
    from tests.sim_helpers import frustum_skirt

    save_mesh(tmp_path / "skirt.obj", frustum_skirt(16, 6))
    args = ["bench", "sim", "--garment", str(tmp_path / "skirt.obj"), "--clips", "walk",
            "--qualities", "", "--settings", "1,2", "--frames", "3", "--transition", "0.1",
            "--settle", "0.0", "--out", str(tmp_path / "b")]  # fmt: skip
    assert main(args) == 0
    table = capsys.readouterr().out
    assert "| walk | 1x2 | 1x2x10 |" in table
    result = json.loads((tmp_path / "b" / "sim.json").read_text())
    (row,) = result["rows"]
    assert row["reference"] == [2, 4, 20] and row["mean_mm"] <= row["p95_mm"]
    assert 0 <= row["frame0_mean_mm"] and 0 <= row["hem_radius_mm"] and 0 <= row["hem_height_mm"]
    assert row["converged"] is None and "needs --floor" in table  # the rule needs a floor
    assert (tmp_path / "b" / "sim.png").stat().st_size > 0
    assert format_table(result["rows"], 96, 3).count("\n") == 4


def test_converged_is_the_floor_rule():
    from app.bench.sim import converged

    row = {"mean_mm": 5.0, "floor_mean_mm": 6.0, "strain_max": 0.05, "strain_limit": 0.1}
    assert converged(row) is True
    assert converged({**row, "mean_mm": 7.0}) is False  # farther from 2x than the floor
    assert converged({**row, "strain_max": 0.2}) is False  # stretched past the limit
    assert converged({k: v for k, v in row.items() if k != "floor_mean_mm"}) is None


def test_sim_overrides_name_only_settings_the_bench_may_change():
    from app.bench.sim import sim_overrides

    assert sim_overrides(["damping=0.5", "fabric=silk"]) == {"damping": 0.5, "fabric": "silk"}
    with pytest.raises(InputError, match="substeps"):
        sim_overrides(["substeps=4"])  # each measured setting decides its own
    with pytest.raises(InputError, match="not a simulation setting"):
        sim_overrides(["stiffness=3"])


def test_floor_runs_the_setting_on_a_moved_garment(tmp_path, capsys):
    from app.cli import main
    from core.mesh import save_mesh
    from core.sim.sanity import perturbed
    from tests.sim_helpers import frustum_skirt

    skirt = frustum_skirt(16, 6)
    moved = perturbed(skirt, 1e-5, 0)
    shift = np.linalg.norm(moved.vertices - skirt.vertices, axis=1)
    assert 0 < shift.max() < 1e-4 and np.array_equal(moved.faces, skirt.faces)
    assert np.array_equal(perturbed(skirt, 1e-5, 0).vertices, moved.vertices)  # seeded
    save_mesh(tmp_path / "skirt.obj", skirt)
    args = ["bench", "sim", "--garment", str(tmp_path / "skirt.obj"), "--clips", "walk",
            "--qualities", "", "--settings", "1,2", "--frames", "3", "--transition", "0.1",
            "--settle", "0.0", "--floor", "--set", "damping=0.5", "--out", str(tmp_path / "b")]  # fmt: skip
    assert main(args) == 0
    table = capsys.readouterr().out
    assert "floor mean / p95 mm" in table
    result = json.loads((tmp_path / "b" / "sim.json").read_text())
    (row,) = result["rows"]
    assert 0 <= row["floor_mean_mm"] <= row["floor_p95_mm"]
    assert row["floor_frame0_mean_mm"] >= 0 and row["floor_hem_radius_mm"] >= 0
    # the floor rule: no farther from the 2x run than from the floor, strain within the limit
    rule = row["mean_mm"] <= row["floor_mean_mm"] and row["strain_max"] <= row["strain_limit"]
    assert row["converged"] is rule and f"| {'yes' if rule else 'no'} |" in table
    assert result["sim"]["damping"] == 0.5 and "substeps" not in result["sim"]


def test_the_implicit_solvers_reference_halves_its_tolerance(tmp_path, capsys):
    from app.cli import main
    from core.mesh import save_mesh
    from tests.sim_helpers import frustum_skirt

    save_mesh(tmp_path / "skirt.obj", frustum_skirt(16, 6))
    args = ["bench", "sim", "--garment", str(tmp_path / "skirt.obj"), "--clips", "walk",
            "--qualities", "", "--settings", "1,4", "--frames", "3", "--transition", "0.1",
            "--settle", "0.0", "--set", "solver=implicit", "--set", "implicit_tol=0.001",
            "--out", str(tmp_path / "b"), "--json"]  # fmt: skip
    assert main(args) == 0
    (row,) = json.loads(capsys.readouterr().out)["rows"]
    assert row["implicit_tol"] == [0.001, 0.0005] and row["reference"] == [2, 8, 20]
    assert np.isfinite(row["mean_mm"]) and row["ms_per_frame"] > 0


def test_hem_statistics_ignore_which_way_a_fold_goes():
    from app.bench.sim import hem_stats_distance
    from core.sim.sanity import hem_indices, waist_indices
    from tests.sim_helpers import frustum_skirt

    skirt = frustum_skirt(16, 6)
    hem = hem_indices(skirt.vertices, skirt.faces)
    waist = np.flatnonzero(skirt.vertices[:, 1] >= skirt.vertices[:, 1].max() - 1e-6)
    # the waist loop, found as the hem is (the highest boundary loop), is the top ring
    assert sorted(waist_indices(skirt.vertices, skirt.faces)) == sorted(waist)
    assert set(hem).isdisjoint(waist) and len(hem) == len(waist) == 16
    run = np.repeat(skirt.vertices[None].astype(np.float64), 3, axis=0)
    assert hem_stats_distance(run, run, hem, waist) == (0.0, 0.0)
    turned = run.copy()  # the hem loop turned about the axis: every vertex moved, nothing else
    c, s = np.cos(0.3), np.sin(0.3)
    x, z = turned[:, hem, 0].copy(), turned[:, hem, 2].copy()
    turned[:, hem, 0], turned[:, hem, 2] = c * x + s * z, -s * x + c * z
    r, y = hem_stats_distance(turned, run, hem, waist)
    assert r < 1e-6 and y < 1e-6 and distance_stats(turned, run)[1] > 10.0
    lifted = run.copy()
    lifted[:, hem, 1] += 0.02
    assert hem_stats_distance(lifted, run, hem, waist)[1] == pytest.approx(20.0)


def test_layers_keep_a_proxy_off_the_body_by_their_depth(tmp_path, capsys):
    """--layers: the garment is a proxy over a target whose inner layer lies 3 cm beneath it:
    every run is simulated with that depth (as dng simulate --layers), and the JSON says so."""
    from app.cli import main
    from core.mesh import Mesh, save_mesh
    from tests.sim_helpers import frustum_skirt

    proxy = frustum_skirt(16, 6)
    v = proxy.vertices.astype(np.float64)
    axis = v.mean(0)
    inner = v.copy()
    radial = inner[:, [0, 2]] - axis[[0, 2]]
    inner[:, [0, 2]] -= 0.03 * radial / np.linalg.norm(radial, axis=1, keepdims=True)
    faces = np.concatenate([proxy.faces, proxy.faces + proxy.num_vertices])
    target = Mesh(np.concatenate([v, inner]).astype(np.float32), faces)
    save_mesh(tmp_path / "proxy.obj", proxy)
    save_mesh(tmp_path / "target.obj", target)
    args = ["bench", "sim", "--garment", str(tmp_path / "proxy.obj"), "--clips", "walk",
            "--qualities", "", "--settings", "1,2", "--frames", "3", "--transition", "0.1",
            "--settle", "0.0", "--out", str(tmp_path / "b"), "--json"]  # fmt: skip
    assert main([*args, "--layers", str(tmp_path / "target.obj")]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["layers"] == str(tmp_path / "target.obj")
    assert result["layers_depth_max_mm"] == pytest.approx(30.0, abs=3.0)
    assert main([*args, "--layers", str(tmp_path / "missing.obj")]) == 2
    assert "missing.obj" in capsys.readouterr().err
