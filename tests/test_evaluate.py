"""Evaluation: frame shifting, scoring methods on the same samples, FID on or honestly off."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest
import torch

from training.baselines import synthetic_batch
from training.evaluate import (
    EvalConfig,
    evaluate_motion,
    garment_region,
    next_frame_batch,
    weights_scores,
)


class _Samples:
    """A map data set over the samples of a synthetic batch."""

    def __init__(self, n: int = 5, size: int = 32):
        self.batch = synthetic_batch(size, batch=n, seed=3)

    def __len__(self) -> int:
        return len(self.batch["target"])

    def __getitem__(self, i: int) -> dict:
        return {k: v[i] for k, v in self.batch.items()}


class _Oracle:
    """Renders the ground truth of the frame at index 1."""

    def render(self, batch: dict) -> torch.Tensor:
        return batch["target"][:, 1].clone()


class _Grey:
    def render(self, batch: dict) -> torch.Tensor:
        return torch.full_like(batch["target"][:, 1], 0.5)


def test_next_frame_batch_moves_one_frame_on():
    b = synthetic_batch(8, batch=2)
    n = next_frame_batch(b)
    for k, v in b.items():
        assert n[k].shape == v.shape
        assert torch.equal(n[k][:, 0], v[:, 1]) and torch.equal(n[k][:, 1], v[:, 2])
    region = garment_region(b)
    assert region.shape == (2, 1, 8, 8) and set(region.unique().tolist()) <= {0.0, 1.0}


def test_methods_are_scored_on_the_same_samples():
    data = _Samples()
    cfg = EvalConfig(batch_size=2, sheet_samples=3)
    results, gt_tiles = evaluate_motion({"oracle": (_Oracle(), data), "grey": (_Grey(), data)}, cfg)
    assert len(gt_tiles) == 3 and gt_tiles[0].shape == (32, 32, 3)
    oracle, grey = results["oracle"].metrics.summary(), results["grey"].metrics.summary()
    # Two scored frames (t, t+1) per sample, one flicker pair per sample.
    assert oracle["mse"]["n"] == 2 * len(data) and oracle["flicker"]["n"] == len(data)
    assert oracle["mse"]["mean"] == 0.0 and oracle["ssim"]["mean"] == pytest.approx(1.0)
    assert oracle["flicker"]["mean"] == 0.0
    assert grey["mse"]["mean"] > 0.01 and grey["ssim"]["mean"] < 0.5
    assert grey["flicker"]["mean"] > 0.0  # a frozen output flickers against a moving truth
    assert len(results["grey"].tiles) == 3 and len(results["grey"].pairs) == len(data)
    json.dumps(oracle)  # JSON-ready (no NaN, no inf)


def test_fid_needs_weights_and_uses_them(tmp_path):
    from training.inception import InceptionV3

    data = _Samples(n=6)
    results, _ = evaluate_motion(
        {"grey": (_Grey(), data)}, EvalConfig(batch_size=3, sheet_samples=1)
    )
    off = weights_scores(results["grey"], EvalConfig())
    assert off["fid"]["value"] is None and "unavailable" in off["fid"]["status"]
    assert off["video_fid"]["value"] is None
    assert off["tlp"]["value"] is None and "no LPIPS weights" in off["tlp"]["status"]
    torch.manual_seed(0)
    weights = tmp_path / "inception_small.pth"
    torch.save(InceptionV3(width_scale=0.125).state_dict(), weights)
    cfg = EvalConfig(inception_path=str(weights), inception_width_scale=0.125)
    on = weights_scores(results["grey"], cfg)
    assert on["fid"]["value"] is not None and on["fid"]["value"] > 0
    assert on["video_fid"]["value"] is not None and on["tlp"]["value"] is None
    from training.lpips import LPIPS

    lpips_file = tmp_path / "lpips_small.pth"
    torch.save(LPIPS(width_scale=0.25).state_dict(), lpips_file)
    cfg = EvalConfig(lpips_path=str(lpips_file), lpips_width_scale=0.25)
    tlp = weights_scores(results["grey"], cfg)["tlp"]
    assert tlp["status"] == "ok" and tlp["pairs"] == len(data) and tlp["value"] >= 0


def _copy(project, tmp_path):
    """A private copy of the shared smoke project (tests that write into it work on this)."""
    copy = tmp_path / "project"
    shutil.copytree(project, copy, ignore=shutil.ignore_patterns("finetune", "ablations"))
    return copy


def test_eval_cli_on_the_smoke_project(smoke_project, tmp_path):
    project = _copy(smoke_project, tmp_path)  # a stage is rerun below: not the shared one
    dng = [sys.executable, "-m", "app.cli"]
    r = subprocess.run(dng + ["eval", str(project)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    for name in ("ours", "ours (simulated proxy)", "pix2pix", "dnr", "dnr-gan"):
        assert name in r.stdout
    assert "garment-region MSE ours / DNR, on Joint2Coarse's proxy:" in r.stdout
    p_lines = r.stdout.split("protocol P (dance, the training motion, unseen cameras):\n")[1]
    assert p_lines.startswith("  garment-region MSE ours / DNR, on Joint2Coarse's proxy:")
    report = json.loads((project / "eval" / "report.json").read_text())
    assert report["test_motions"] == ["twirl", "cmu-01_01"]
    for name, m in report["methods"].items():
        assert m["mse"]["n"] > 0 and 0 <= m["mse"]["mean"] <= 1, name
        assert 0 < m["ssim"]["mean"] <= 1 and m["flicker"]["n"] > 0, name
    assert report["mse_ratio_ours_to_dnr"] > 0 and report["mse_masked_ratio_ours_to_dnr"] > 0
    assert (project / "eval" / "twirl" / "compare.png").stat().st_size > 1000
    # --json: stdout is the report alone (progress on stderr), even when stages rerun. One
    # motion scored again gives the same pooled report: each motion's frames are kept.
    (project / "eval" / "twirl" / "stage.json").unlink()
    r = subprocess.run(dng + ["eval", str(project), "--json"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) == report
    assert "evaluating twirl" in r.stderr and "evaluating cmu-01_01" not in r.stderr
    missing = tmp_path / "nope.pth"
    r = subprocess.run(
        dng + ["eval", str(project), "--inception", str(missing)],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "nope.pth" in r.stderr and r.stderr.count("\n") == 1


def test_ablations_train_and_join_the_table(smoke_project, tmp_path):
    from core.project import Project
    from pipeline.config import project_config
    from pipeline.stages.ablations import ablation_label

    copy = _copy(smoke_project, tmp_path)
    dng = [sys.executable, "-m", "app.cli", "eval", str(copy)]
    r = subprocess.run(
        dng + ["--ablations", "no-motion", "no-temporal", "views-3"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    config = project_config(Project(copy))
    assert config.ablations == ("no-motion", "no-temporal", "views-3")  # kept for the next eval
    report = json.loads((copy / "eval" / "report.json").read_text())
    for name in config.ablations:
        m = report["methods"][ablation_label(name, config)]
        assert m["mse"]["n"] == report["methods"]["ours"]["mse"]["n"]
    # scored on the validation motion too, where the choices are made
    assert ablation_label("no-temporal", config) in report["validation"]["methods"]
    trained = json.loads((copy / "ablations/no-temporal/report.json").read_text())
    assert trained["config"]["use_temporal"] is False
    views = json.loads((copy / "ablations/views-3/dataset/samples.json").read_text())["samples"]
    assert {s["view"] for s in views} == {0, 1, 2}
    assert (copy / "ablations/views-3/proxy").is_symlink()  # shared, not copied
    r = subprocess.run(dng + ["--ablations", "views-x"], capture_output=True, text=True)
    assert r.returncode == 2 and "unknown ablation 'views-x'" in r.stderr


@pytest.mark.slow
def test_template_proxy_ablation(smoke_project, tmp_path):
    from dataclasses import replace

    from core.project import Project
    from pipeline.config import PRESETS
    from pipeline.stages.ablations import stage_ablation
    from pipeline.stages.evaluate import stage_eval

    copy = _copy(smoke_project, tmp_path)
    config = replace(PRESETS["smoke"], ablations=("template-short-skirt",))
    report = stage_ablation(Project(copy), config, "template-short-skirt")
    assert report["steps"] == config.renderer_steps
    sub = copy / "ablations" / "template-short-skirt"
    assert json.loads((sub / "proxy" / "stage.json").read_text())["params"]["template"]
    result = stage_eval(Project(copy), config)
    assert "ours, short-skirt template as proxy" in result["methods"]


def test_ours_to_dnr_gives_garment_region_and_full_frame_ratios():
    from pipeline.demo import metrics_table, ratio_sentence
    from pipeline.stages.evaluate import ours_to_dnr

    def method(mse, masked):
        s = {"mean": 0.5, "std": 0.1, "n": 4}
        return {"mse": {"mean": mse, "std": 0.0, "n": 4}, "mse_masked": {**s, "mean": masked},
                "psnr": s, "ssim": s, "ssim_masked": s, "flicker": s}  # fmt: skip

    methods = {"ours": method(0.006, 0.04), "dnr": method(0.008, 0.032),
               "ours (simulated proxy)": method(0.002, 0.01)}  # fmt: skip
    r = ours_to_dnr(methods)
    assert r["mse_ratio_ours_to_dnr"] == pytest.approx(0.75)
    assert r["mse_masked_ratio_ours_to_dnr"] == pytest.approx(1.25)
    assert not any(k.endswith("simulated_proxy") for k in r)  # DNR did not run on it
    text = ratio_sentence(methods)
    assert text.index("garment-region MSE 1.25") < text.index("full-frame MSE 0.75")
    header = metrics_table(methods)[0]
    assert header.index("MSE, garment") < header.index("| MSE |")  # the headline first
    assert ours_to_dnr({"ours": methods["ours"]}) == {} and ratio_sentence({}) == ""
