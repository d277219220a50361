"""``dng bench placement``: every method's image error as the proxy moves from simulation to
Joint2Coarse's prediction."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from core.errors import InputError


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


# ------------------------------------------------------------------------- pieces


def test_blend_positions_moves_the_error_linearly():
    from app.bench.placement import blend_positions
    from training.joint2coarse import vertex_errors

    def mean_error_mm(a, b):
        return vertex_errors(a, b).mean_mm

    rng = np.random.default_rng(0)
    sim = rng.normal(size=(4, 7, 3)).astype(np.float32)
    pred = (sim + rng.normal(scale=0.05, size=sim.shape)).astype(np.float32)
    np.testing.assert_array_equal(blend_positions(sim, pred, 0.0), sim)
    np.testing.assert_array_equal(blend_positions(sim, pred, 1.0), pred)
    half = blend_positions(sim, pred, 0.5)
    assert half.dtype == np.float32
    np.testing.assert_allclose(half, (sim.astype(np.float64) + pred) / 2, atol=1e-6)
    full = mean_error_mm(pred, sim)
    assert full > 0
    for s in (0.1, 0.25, 2.0):
        assert math.isclose(
            mean_error_mm(blend_positions(sim, pred, s), sim), s * full, rel_tol=1e-5
        )
    with pytest.raises(InputError, match="same"):
        blend_positions(sim, pred[:, :5], 0.5)
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(InputError, match="scale"):
            blend_positions(sim, pred, bad)


def test_scales_and_ratios():
    from app.bench.placement import check_scales, ratios

    assert check_scales([1, 0, 0.5, 1.0]) == [0.0, 0.5, 1.0]
    with pytest.raises(InputError, match="--scales"):
        check_scales([0.5, -1])
    assert ratios({"ours": 0.002, "dnr": 0.004, "pix2pix": 0.0}) == {"ours/dnr": 0.5}
    assert ratios({"dnr": 0.004}) == {}


def test_dataset_renders_given_positions(smoke_project):
    from core.sim import load_cache
    from training.dataset import GarmentDataset

    sim = load_cache(smoke_project / "sim" / "twirl-proxy" / "cache.npz").positions
    given = GarmentDataset(smoke_project, "joint2coarse", split="twirl", proxy_positions=sim)
    cached = GarmentDataset(smoke_project, "sim", split="twirl")
    a, b = given[0], cached[0]
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=0, atol=0)
    index = smoke_project / "testset" / "twirl" / "samples.json"
    bad = sim.copy()
    bad[3, 5, 1] = np.nan
    with pytest.raises(InputError, match="NaN") as err:
        GarmentDataset(smoke_project, "sim", split="twirl", proxy_positions=bad)
    assert str(index) in str(err.value)
    with pytest.raises(InputError, match=r"\(frames, vertices, 3\)"):
        GarmentDataset(smoke_project, "sim", split="twirl", proxy_positions=sim[0])
    with pytest.raises(InputError, match="frames"):  # a clip of the wrong length
        GarmentDataset(smoke_project, "sim", split="twirl", proxy_positions=sim[:-2])


# ------------------------------------------------------------------------- the bench


def test_placement_bad_input_exits_2(smoke_project, tmp_path, dng):
    out = tmp_path / "o"
    code, _, err = dng("bench", "placement", "--project", tmp_path / "nope", "--out", out)
    assert code == 2 and "not found" in err
    code, _, err = dng(
        "bench", "placement", "--project", smoke_project, "--out", out, "--scales", 0, -0.5
    )
    assert code == 2 and "--scales" in err
    code, _, err = dng(
        "bench", "placement", "--project", smoke_project, "--out", out, "--methods", "nope"
    )
    assert code == 2 and "unknown method(s) nope" in err and "dnr" in err
    code, _, err = dng(
        "bench", "placement", "--project", smoke_project, "--out", out, "--motions", "nope"
    )
    assert code == 2 and "no test set for nope" in err
    assert not out.exists()


def test_placement_on_smoke_project(smoke_project, tmp_path, dng):
    """The ends of the line reproduce dng eval: scale 0 is the simulated proxy, 1 Joint2Coarse's."""
    before = sorted(p.relative_to(smoke_project) for p in smoke_project.rglob("*"))
    out = tmp_path / "placement"
    code, text, err = dng(
        "bench", "placement", "--project", smoke_project, "--out", out, "--scales", 1, 0, 0.5,
        "--methods", "ours", "dnr", "--json",
    )  # fmt: skip
    assert code == 0, err
    table = json.loads(text)
    assert table == json.loads((out / "placement.json").read_text())
    assert table["complete"] and table["methods"] == ["ours", "dnr"]
    assert (out / "placement.png").stat().st_size > 1000
    labels = [r["label"] for r in table["rows"]]
    assert labels == ["scale 0", "scale 0.5", "scale 1", "autoencoder"]
    zero, half, one, auto = table["rows"]
    evaluation = json.loads((smoke_project / "eval" / "report.json").read_text())["methods"]
    for row, suffix in ((zero, " (simulated proxy)"), (one, "")):
        for name in ("ours", "dnr"):
            expected = evaluation[f"{name}{suffix}"]["mse"]["mean"]
            assert math.isclose(row["mse"][name], expected, rel_tol=1e-6), (row["label"], name)
        assert math.isclose(row["ratios"]["ours/dnr"], row["mse"]["ours"] / row["mse"]["dnr"])
    j2c = table["joint2coarse_error_mm"]
    assert set(j2c) == {"twirl", "cmu-01_01"} and all(v > 0 for v in j2c.values())
    assert zero["error_mm"] == {"twirl": 0.0, "cmu-01_01": 0.0}
    for motion, mm in j2c.items():
        assert math.isclose(one["error_mm"][motion], mm, rel_tol=1e-5)
        assert math.isclose(half["error_mm"][motion], mm / 2, rel_tol=1e-5)
    # The autoencoder row agrees with the Joint2Coarse stage's own figure for it.
    report = json.loads((smoke_project / "joint2coarse" / "report.json").read_text())
    for motion in j2c:
        expected = report["motions"][motion]["autoencoder_error_mm"]["mean_mm"]
        assert math.isclose(j2c[motion], report["motions"][motion]["error_mm"]["mean_mm"],
                            rel_tol=1e-3), motion  # fmt: skip
        assert math.isclose(auto["error_mm"][motion], expected, rel_tol=1e-3), motion
    for row in table["rows"]:
        for name in ("ours", "dnr"):
            assert 0 < row["mse"][name] < 1 and 0 < row["ssim"][name] <= 1
    # Nothing written into the project.
    assert sorted(p.relative_to(smoke_project) for p in smoke_project.rglob("*")) == before
