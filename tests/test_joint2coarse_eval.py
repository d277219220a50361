"""``dng eval joint2coarse``: Joint2Coarse against the simulation on any motion, and the
simulation's own colliders for push-out and penetration."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from core.body.colliders import body_capsules, simulation_colliders
from core.body.shape import CHEST_LEVEL, BodyShape, mannequin_skeleton
from core.motion.procedural import make_motion
from training.joint2coarse import push_out_of_capsules
from training.joint2coarse.collision import penetration_summary


@pytest.fixture
def scratch(tmp_path, monkeypatch):
    """Evaluation simulations are cached here, not in the user's cache."""
    cache = tmp_path / "xdg-cache"
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
    return cache


def test_simulation_colliders_are_the_simulations_capsules():
    shape = BodyShape()
    motion = make_motion("walk", 12, 30.0, 0, shape)
    low = CHEST_LEVEL * shape.height - 0.1
    ends, radii = simulation_colliders(shape, motion, garment_top=low)
    all_caps = body_capsules(mannequin_skeleton(shape), shape)
    arms = sum("Arm" in n for n in all_caps.names)
    assert ends.shape == (12, all_caps.count - arms, 2, 3) and radii.shape == (
        all_caps.count - arms,
    )
    ends_arms, radii_arms = simulation_colliders(shape, motion, garment_top=low, arm_colliders=True)
    assert ends_arms.shape[1] == all_caps.count
    np.testing.assert_allclose(radii_arms, all_caps.radii)
    # A point on a capsule's axis is inside it; pushed out, it is outside every capsule.
    centre = ends[:, :1].mean(axis=2)  # (T, 1, 3): the middle of the first capsule's axis
    pen = penetration_summary(centre, ends, radii)
    assert pen["inside_percent"] == 100.0 and pen["max_mm"] >= 1e3 * radii[0] - 1e-3
    pushed = push_out_of_capsules(centre, ends, radii)
    assert penetration_summary(pushed, ends, radii)["inside_percent"] == 0.0


def test_eval_joint2coarse_on_a_kind(smoke_project, scratch, dng):
    args = ("eval", "joint2coarse", smoke_project, "--motion", "walk", "--frames", 36)
    code, out, err = dng(*args, "--json")
    assert code == 0, err
    report = json.loads(out)  # only JSON on stdout
    assert report["frames"] == 36 and report["motion"] == "walk"
    assert not report["simulation_from_cache"]
    assert str(scratch) in report["simulation_cache"]
    assert not any(smoke_project in p.parents for p in scratch.rglob("*"))
    e = report["error_mm"]
    assert 0 < e["mean_mm"] <= e["p95_mm"] <= e["max_mm"] < 1e3
    # Each second's error: 36 frames at 30 fps are a second and 6 frames, whose means
    # weighted by their frames give the whole motion's.
    seconds = report["error_mm_per_second"]
    assert [w["start_s"] for w in seconds] == [0.0, 1.0]
    assert max(w["max_mm"] for w in seconds) == e["max_mm"]
    assert abs((30 * seconds[0]["mean_mm"] + 6 * seconds[1]["mean_mm"]) / 36 - e["mean_mm"]) < 1e-6
    pen = report["penetration"]
    for key in ("prediction", "prediction_pushed_out", "simulation"):
        assert 0.0 <= pen[key]["inside_percent"] <= 100.0 and pen[key]["max_mm"] >= 0.0
    assert pen["prediction_pushed_out"]["inside_percent"] == 0.0
    # stretch and the hem's radius beside the penetration, for prediction and simulation alike
    stretch, hem = report["stretch"], report["hem_radius_mm"]
    for key in ("prediction", "prediction_pushed_out", "simulation"):
        assert 0.0 <= stretch[key]["p99"] <= stretch[key]["max"] < 10.0
        assert 50.0 < hem[key]["mean"] < 1000.0 and hem[key]["mean_difference"] >= 0.0
    assert hem["simulation"]["mean_difference"] == 0.0 and hem["prediction"]["mean_difference"] > 0
    # The smoke preset trains our model beside the paper's: both are scored.
    assert report["model"] == "paper" and set(report["compare_error_mm"]) == {"ours"}
    assert report["compare_error_mm"]["ours"]["mean_mm"] > 0
    ms = report["ms_per_frame"]
    assert ms["simulation"] > 0 and ms["prediction"] > 0 and ms["prediction_streaming"] > 0
    # Again: the simulation comes from the scratch cache, and so do the same figures.
    code, out, err = dng(*args, "--json")
    again = json.loads(out)
    assert code == 0 and again["simulation_from_cache"]
    assert again["error_mm"] == report["error_mm"]
    # The text form names every row.
    code, out, _ = dng(*args)
    assert code == 0
    assert all(w in out for w in ("Joint2Coarse", "pushed out", "simulation", "mean mm"))
    assert (
        "stretch p99" in out and "hem radius mm" in out and "differs from the simulation's" in out
    )
    assert "mean error each second (mm)" in out and "the worst from" in out
    assert again["simulation_floor_mm"] is None and "moved 10 um" not in out
    assert again["simulation_floor_mm_per_second"] is None and "floor each second" not in out
    # --floor: the simulation again on the proxy moved 10 um, cached beside the first.
    code, out, err = dng(*args, "--floor", "--json")
    floored = json.loads(out)
    assert code == 0 and floored["simulation_from_cache"], err
    f = floored["simulation_floor_mm"]
    assert 0 < f["mean_mm"] <= f["p95_mm"] <= f["max_mm"] < 1e3
    assert floored["error_mm"] == report["error_mm"]
    assert len([p for p in scratch.rglob("cache.npz")]) == 2
    floor_seconds = floored["simulation_floor_mm_per_second"]
    assert [w["start_s"] for w in floor_seconds] == [0.0, 1.0]
    assert max(w["max_mm"] for w in floor_seconds) == f["max_mm"]
    code, out, _ = dng(*args, "--floor")
    assert code == 0 and "simulation, proxy moved 10 um" in out and "floor each second" in out
    assert floored["realisations"] is None and "simulations (the proxy moved" not in out
    # --realisations 2: two simulations of the proxy moved 10 um (the first is the floor's,
    # from the cache), every model scored against all three.
    code, out, err = dng(*args, "--realisations", 2, "--json")
    assert code == 0, err
    r = json.loads(out)["realisations"]
    assert r["simulations"] == 3 and len([p for p in scratch.rglob("cache.npz")]) == 3
    assert set(r["error_mm"]) == {"paper", "ours"}
    for model, e in r["error_mm"].items():
        each = e["mean_mm_each"]
        assert len(each) == 3 and abs(e["mean_mm"] - np.mean(each)) < 1e-9
        first = report["error_mm"] if model == "paper" else report["compare_error_mm"]["ours"]
        assert abs(each[0] - first["mean_mm"]) < 1e-9  # the first is the reference
    between = r["between_simulations_mm"]["mean_mm_each"]  # pairs (0, 1), (0, 2), (1, 2)
    assert len(between) == 3 and abs(between[0] - f["mean_mm"]) < 1e-9
    assert len(set(between)) == 3  # each moved simulation has offsets of its own
    # the mean of the other two against each: the midpoint of two draws lies nearer a third
    # than the average pair does (by the triangle inequality, vertex by vertex: never farther)
    others = r["mean_of_others_mm"]
    assert len(others["mean_mm_each"]) == 3 and others["mean_mm"] > 0
    assert others["mean_mm"] <= np.mean(between) + 1e-9
    ratio = r["ensemble_ratio"]  # each model's mean error over the mean of the others'
    assert set(ratio) == {"paper", "ours"}
    assert all(
        abs(ratio[m] - r["error_mm"][m]["mean_mm"] / others["mean_mm"]) < 1e-9 for m in ratio
    )
    code, out, _ = dng(*args, "--realisations", 2)
    assert code == 0 and "against 3 simulations" in out and "each pair" in out
    assert "the mean of the others" in out and f"paper {ratio['paper']:.2f}x" in out
    code, _, err = dng(*args, "--realisations", 0)
    assert code == 2 and "--realisations must be at least 1" in err


def test_eval_joint2coarse_on_capture(smoke_project, scratch, dng, bvh_dir):
    clip = bvh_dir / "01_01.bvh"
    code, out, err = dng(
        "eval", "joint2coarse", smoke_project, "--motion", clip,
        "--start-s", 2.0, "--frames", 34, "--json",
    )  # fmt: skip
    assert code == 0, err
    report = json.loads(out)
    assert report["frames"] == 34 and np.isfinite(report["error_mm"]["mean_mm"])


def test_eval_joint2coarse_on_a_deepmimic_capture(smoke_project, scratch, dng, deepmimic_dir):
    """A DeepMimic file goes straight in (60 fps keyframes, resampled to the project's fps)."""
    clip = deepmimic_dir / "humanoid3d_dance_b.txt"
    code, out, err = dng(
        "eval", "joint2coarse", smoke_project, "--motion", clip, "--frames", 34, "--json"
    )
    assert code == 0, err
    report = json.loads(out)
    assert report["frames"] == 34 and np.isfinite(report["error_mm"]["mean_mm"])


def test_eval_joint2coarse_refuses_bad_input(smoke_project, scratch, dng, tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n")
    code, out, err = dng("eval", "joint2coarse", smoke_project, "--motion", bad)
    assert code == 2 and str(bad) in err and len(err.strip().splitlines()) == 1
    code, _, err = dng("eval", "joint2coarse", smoke_project, "--motion", "walk", "--frames", 10)
    assert code == 2 and "window" in err and len(err.strip().splitlines()) == 1
    code, _, err = dng("eval", "joint2coarse", smoke_project, "--motion", tmp_path / "none.bvh")
    assert code == 2 and "none.bvh" in err
    short = tmp_path / "short.txt"
    short.write_text('{"Loop": "none", "Frames": [[0.1, 1, 2]]}')
    code, _, err = dng("eval", "joint2coarse", smoke_project, "--motion", short)
    assert code == 2 and str(short) in err and "has 3 values" in err
    # A project with no trained Joint2Coarse (a copy without it: the shared one stays as it is).
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(smoke_project / "project.json", bare / "project.json")
    shutil.copytree(smoke_project / "proxy", bare / "proxy")
    code, _, err = dng("eval", "joint2coarse", bare, "--motion", "walk", "--frames", 40)
    assert code == 2 and "joint2coarse.pt" in err and len(err.strip().splitlines()) == 1
    assert not scratch.exists()  # nothing simulated for refused input


def test_the_ensemble_ratio_has_a_known_answer():
    """Three simulations 1 mm apart along x (0, 1, 2 mm): the mean of the other two is 1.5, 0
    and 1.5 mm from each (1 mm on average); a prediction on the middle one is 1, 0 and 1 mm
    from them (2/3 mm): its ensemble ratio is 2/3. One on the first is 0, 1, 2 mm off: 1x."""
    from pipeline.joint2coarse_eval import realisation_errors

    base = np.zeros((4, 5, 3))
    sims = [base + np.array([0.001 * i, 0.0, 0.0]) for i in range(3)]
    r = realisation_errors({"middle": sims[1], "first": sims[0]}, sims)
    assert np.allclose(r["mean_of_others_mm"]["mean_mm_each"], [1.5, 0.0, 1.5])
    assert np.isclose(r["error_mm"]["middle"]["mean_mm"], 2 / 3)
    assert np.isclose(r["ensemble_ratio"]["middle"], 2 / 3)
    assert np.isclose(r["ensemble_ratio"]["first"], 1.0)
    # two simulations have no mean of the others: no ratio
    assert realisation_errors({"middle": sims[1]}, sims[:2])["ensemble_ratio"] is None


def test_proxy_physics_known_answers():
    """A skirt stretched 10 % about its waist's axis: stretch 0.1 on its round edges, its hem's
    radius 1.1x; the skirt as it is: no stretch; one vertex inside a capsule: penetration."""
    from pipeline.stages.joint2coarse import proxy_physics
    from tests.sim_helpers import frustum_skirt

    skirt = frustum_skirt()
    rest = skirt.vertices.astype(np.float64)
    axis = rest.mean(0)
    wide = rest.copy()
    wide[:, [0, 2]] = axis[[0, 2]] + 1.1 * (rest[:, [0, 2]] - axis[[0, 2]])
    far = np.array([[[[5.0, 0.0, 0.0], [5.0, 1.0, 0.0]]]])  # a capsule far from the skirt
    both = np.stack([rest, wide])
    phys = proxy_physics(both, rest, skirt.faces, np.repeat(far, 2, 0), np.array([0.05]))
    radius = phys["hem_radius_mm"]
    assert np.isclose(radius[1] / radius[0], 1.1, rtol=1e-3)
    assert np.isclose(phys["stretch"]["max"], 0.1, atol=1e-3)
    assert phys["penetration_mm"]["fraction"] == 0.0
    alone = proxy_physics(rest[None], rest, skirt.faces, far, np.array([0.05]))
    assert abs(alone["stretch"]["max"]) < 1e-6 and alone["stretch"]["p99"] < 1e-6
    # a capsule 2 cm across round the first vertex: it is 2 cm inside, the rest outside
    v = rest[0]
    inside = np.array([[[v - [0, 0.01, 0], v + [0, 0.01, 0]]]])
    pen = proxy_physics(rest[None], rest, skirt.faces, inside, np.array([0.02]))["penetration_mm"]
    assert np.isclose(pen["max"], 20.0, atol=0.5) and 0 < pen["fraction"] < 0.01
