"""``benchmarks/renderer_validation.py``: a method retrained outside the project and scored on
the renderers' validation motion (protocol V), the figures its settings are chosen on."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "renderer_validation.py"
ROOT = BENCH.parents[1]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(BENCH), *args], cwd=ROOT, capture_output=True, text=True, timeout=600
    )


def test_the_bench_reproduces_the_projects_validation_figures(smoke_project, tmp_path):
    project = tmp_path / "project"
    shutil.copytree(smoke_project, project, symlinks=True)
    before = {p: p.stat().st_mtime_ns for p in (project / "baselines").rglob("*")}
    run = _run(str(project), "--method", "dnr-gan", "--json")  # its trainer prints a line too
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out["motion"] == "val-walk" and [r["seed"] for r in out["runs"]] == [0]
    assert out["source"] == "joint2coarse"  # the project's renderer_source
    # Same settings, same seed: the project's own model scores the same on V (eval/report.json).
    scored = json.loads((project / "eval" / "report.json").read_text())["validation"]["methods"]
    for src, name in (("joint2coarse", "dnr-gan"), ("sim", "dnr-gan (simulated proxy)")):
        for metric in (
            "mse_masked",
            "gmsd_masked",
            "gms_masked",
            "detail_masked",
            "ssim_masked",
            "mse",
            "flicker",
        ):
            assert abs(out["runs"][0]["figures"][src][metric] - scored[name][metric]["mean"]) < 1e-6
    # Nothing of the project was retrained or rewritten.
    assert before == {p: p.stat().st_mtime_ns for p in (project / "baselines").rglob("*")}


def test_a_changed_setting_trains_another_model_and_says_so(smoke_project, tmp_path):
    project = tmp_path / "project"
    shutil.copytree(smoke_project, project, symlinks=True)
    keep = tmp_path / "kept"
    run = _run(
        str(project), "--method", "ours", "--set", "lr_decay_from=1.0", "--seeds", "0", "1",
        "--keep", str(keep),
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    # --keep: each seed's model, loadable, with the changed setting in it
    from training.renderer.train import load_model

    assert sorted(p.name for p in keep.iterdir()) == ["ours-seed-0.pt", "ours-seed-1.pt"]
    assert load_model(keep / "ours-seed-1.pt")[0].lr_decay_from == 1.0
    assert (
        "ours on val-walk (validation), trained over the proxy 'joint2coarse', settings changed: "
        "{'lr_decay_from': 1.0}" in run.stdout
    )
    assert run.stdout.count("seed 0 ") == 2 and run.stdout.count("seed all") == 2
    # the simulated proxy instead of the project's: another model, other figures
    run = _run(str(project), "--method", "dnr", "--source", "sim", "--json")
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    scored = json.loads((project / "eval" / "report.json").read_text())["validation"]["methods"]
    assert out["source"] == "sim"
    assert out["runs"][0]["figures"]["sim"]["mse"] != scored["dnr (simulated proxy)"]["mse"]["mean"]


def test_a_project_without_a_validation_motion_is_told_what_to_give(smoke_project, tmp_path):
    project = tmp_path / "project"
    shutil.copytree(smoke_project, project, symlinks=True)
    settings = json.loads((project / "project.json").read_text())
    settings["pipeline"]["renderer_validation"] = None
    (project / "project.json").write_text(json.dumps(settings))
    run = _run(str(project), "--method", "dnr")
    assert run.returncode == 2 and "give --motion NAME" in run.stderr
    run = _run(str(project), "--method", "dnr", "--motion", "twirl")
    assert run.returncode == 2 and "is not one of the validation motions" in run.stderr
    run = _run(str(tmp_path / "nowhere"), "--method", "dnr")
    assert run.returncode == 2 and "not a garment project" in run.stderr


def test_an_extra_training_motion_adds_its_samples_and_a_test_motion_is_refused(
    smoke_project, tmp_path
):
    project = tmp_path / "project"
    shutil.copytree(smoke_project, project, symlinks=True)
    run = _run(
        str(project), "--method", "dnr", "--steps", "2", "--extra-motion", "circle-walk", "--json"
    )
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    index = json.loads((project / "renderer-extra" / "circle-walk" / "samples.json").read_text())
    own = json.loads((project / "dataset" / "samples.json").read_text())
    assert index["motion"] == "circle-walk" and out["extra_motions"] == ["circle-walk"]
    assert out["samples"] == len(own["samples"]) + len(index["samples"]) > len(own["samples"])
    # the clip's cameras are the training set's stream, views and stride
    assert {s["view"] for s in index["samples"]} == {s["view"] for s in own["samples"]}
    run = _run(str(project), "--method", "dnr", "--steps", "2", "--extra-motion", "twirl")
    assert (
        run.returncode == 2 and "'twirl' is not one of Joint2Coarse's training clips" in run.stderr
    )
    assert not (project / "renderer-extra" / "twirl").exists()
