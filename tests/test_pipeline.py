"""The main job end to end: the smoke preset of ``dng demo`` on the built-in assets."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from core.errors import InputError
from core.project import Project, fingerprint
from pipeline.config import PRESETS, PipelineConfig, preset, project_config


@pytest.fixture(scope="module")
def smoke(smoke_project):
    return smoke_project, json.loads((smoke_project / "report.json").read_text())


def test_smoke_demo_runs_every_stage_and_reports(smoke):
    out, report = smoke
    assert (out / "report.md").is_file() and (out / "report.json").is_file()
    on_disk = json.loads((out / "report.json").read_text())
    assert on_disk["command"].startswith("dng demo --preset smoke")
    assert set(report["simulation"]) == {
        "dance-proxy",
        "dance-target",
        "twirl-proxy",
        "cmu-01_01-proxy",
        "twirl-target",
        "cmu-01_01-target",
        "circle-walk-proxy",
        "val-walk-proxy",
        "val-walk-target",  # the renderers' validation motion
    }
    for name, sim in report["simulation"].items():
        assert sim["finite"], name
        assert sim["penetration_mean_mm"] < 5.0, name
        if name.endswith("-proxy"):  # simulated (the targets are embedded): its hem's ratio
            assert 0.3 < sim["hem_radius_ratio"] < 3.0, name
            assert sim["waistband_rise_max_mm"] <= 50.0, name  # issue 55: the waistband holds
            standing = (
                sim["end_tilt_deg"] <= 30.0
                and sim["end_hips_height"] >= 0.85
                and sim["end_feet_m"] <= 0.7
            )
            assert (sim["hem_rise_end_mm"] is not None) == standing, name  # measured standing
        else:  # embedded and kept out of the body, without a tear
            assert sim["contact"]["margin"] > 0 and sim["penetration_max_mm"] == 0.0, name
            assert sim["torn_edges"] == 0 and sim["strain_p99"] <= 0.1, name
    assert (
        "| hem ratio | waistband drift (mm) | hem at end (mm) |" in (out / "report.md").read_text()
    )
    proxy = report["proxy"]["proxy"]
    assert proxy["boundary_loops"] == 2 and proxy["components"] == 1
    j2c = report["joint2coarse"]
    assert set(j2c["motions"]) == {"twirl", "cmu-01_01"}
    assert j2c["extra_train_motions"] == ["circle-walk"]  # trained on two clips
    # Three splits; the paper's model is the project's, ours trains beside it on the same ones.
    assert j2c["splits"] == {
        "train": ["dance", "circle-walk"], "validation": ["val-walk"],
        "test": ["twirl", "cmu-01_01"],
    }  # fmt: skip
    assert j2c["model"] == "paper" and set(j2c["compare"]) == {"ours"}
    for key, names in (("validation_motions", ["val-walk"]), ("motions", ["twirl", "cmu-01_01"])):
        assert list(j2c[key]) == names and list(j2c["compare"]["ours"][key]) == names
        for m in j2c[key].values():
            assert m["simulation_penetration_mm"]["max"] >= 0.0
            pushed, raw = m["with_push_out"]["penetration_mm"], m["penetration_mm"]
            assert pushed["fraction"] <= raw["fraction"] and pushed["max"] <= raw["max"]
            # physics beside the distance: the edges' stretch of prediction and simulation
            for s in (m["stretch"], m["with_push_out"]["stretch"], m["simulation_stretch"]):
                assert 0.0 <= s["p99"] <= s["max"] < 10.0
            # ... and the hem's radius per frame, of both, in millimetres
            r, sim = np.asarray(m["hem_radius_mm"]), np.asarray(m["simulation_hem_radius_mm"])
            assert r.shape == sim.shape == (m["frames"],) and (sim > 50).all() and (r > 0).all()
    for m in j2c["motions"].values():
        e = m["error_mm"]
        assert np.isfinite([e["mean_mm"], e["p95_mm"]]).all() and 0 < e["mean_mm"] < e["p95_mm"]
    md = (out / "report.md").read_text()
    assert "dng demo --preset smoke" in md and "unseen `cmu-01_01`" in md
    lines = md.splitlines()
    head = next(i for i, line in enumerate(lines) if "| stretch p99 / max |" in line)
    rows = lines[head + 2 : head + 4]
    assert [r.split(" | ")[0] for r in rows] == ["| `twirl`", "| `cmu-01_01`"]
    assert all("-" not in r.replace(" | ", "|").split("|") for r in rows)  # every figure there
    # The ground truth names its mode, its strain and shows a contact sheet per clip.
    assert "## Ground truth: the detailed target" in md and "embedded in the proxy" in md
    # ... in a proxy kept off the body by the layers beneath it, which its report says
    assert "simulated kept off the body by the layers beneath it" in md
    notes = report["simulation"]["dance-proxy"]["notes"]
    assert any(n.startswith("kept off the body by the layers") for n in notes)
    for clip in ("dance", "val-walk", "twirl", "cmu-01_01"):
        target = report["simulation"][f"{clip}-target"]
        assert target["mode"] == "embed" and 0 <= target["strain_p99"] <= target["strain_max"]
        assert (out / "sim" / f"{clip}-target" / "sheet.png").is_file()
        assert f"](sim/{clip}-target/sheet.png)" in md
    assert "the shape autoencoder on its simulated shapes" in md
    # Two protocols: U (the unseen test motions) and P (the training motion, unseen cameras).
    ev = report["evaluation"]
    assert set(ev["motions"]) == {"twirl", "cmu-01_01"}
    p = ev["protocol_p"]
    assert p["motion"] == "dance" and set(p["methods"]) == set(ev["methods"])
    assert 0 < p["mse_ratio_ours_to_dnr"] and 0 < p["methods"]["ours"]["mse"]["mean"]
    assert (out / "testset" / "dance" / "samples.json").is_file()
    # V: the validation motion from cameras of its own, every method scored, apart from U's.
    v = ev["validation"]
    assert v["motion"] == "val-walk" and set(v["methods"]) == set(ev["methods"])
    assert 0 < v["mse_masked_ratio_ours_to_dnr"] and "val-walk" not in ev["motions"]
    assert "(protocol V)" in md and "](eval/val-walk/compare.png)" in md
    from pipeline.stages.dataset import VALIDATION_CAMERAS

    stage = json.loads((out / "testset/val-walk/stage.json").read_text())
    assert stage["params"]["cameras"] == VALIDATION_CAMERAS  # a stream no test set uses
    assert "(protocol P, the paper's)" in md and "](eval/dance/compare.png)" in md
    assert "(discriminator), falling linearly to zero from step 15." in md  # of 30
    # the baselines train on our schedule
    for kind in ("pix2pix", "dnr", "dnr-gan"):
        assert f"- baseline `{kind}`: 30 steps" in md
    assert md.count("learning rates falling linearly to zero from step 15") == 3
    for m in j2c["motions"].values():
        assert 0 < m["autoencoder_error_mm"]["mean_mm"] < m["autoencoder_error_mm"]["p95_mm"]
    # The time-left estimate has one expected cost per stage the demo ran, in its order.
    from pipeline.demo import stage_costs

    costs = stage_costs(PRESETS["smoke"])
    assert len(costs) == len(report["stage_seconds"])
    names = list(report["stage_seconds"])
    assert names[0] == "motions" and names[-1].startswith("evaluation (protocols V, U and P")
    # the evaluation one motion at a time (in either lane), then the report that pools them
    for motion in ("val-walk", "twirl", "cmu-01_01", "dance"):
        assert any(n.startswith(f"evaluation of {motion} (protocol ") for n in names[:-1])
        assert (out / "eval" / motion / "compare.png").is_file()
    # With a core for each, the simulations ran two at a time; the table keeps the stages' order.
    sims = [n for n in names if n.startswith("simulate ")]
    assert sims[0] == "simulate dance (proxy)" and sims[-1].endswith("(target)")
    # every embedded target read one binding to the proxy, made before the first of them
    from pipeline.demo import EMBEDDING_STAGE

    binding = names.index(EMBEDDING_STAGE)
    assert names.index("proxy") < binding < names.index(sims[0])
    for clip in ("dance", "val-walk", "twirl", "cmu-01_01"):
        record = json.loads((out / "sim" / f"{clip}-target" / "stage.json").read_text())
        inputs = [out / "garment" / "target.obj", out / "proxy" / "positions.obj"]
        inputs += [out / "embedding" / "embedding.npz", out / "sim" / f"{clip}-proxy" / "cache.npz"]
        assert record["fingerprint"] == fingerprint(record["params"], inputs)  # the binding's in
    if (os.cpu_count() or 1) >= 2:
        assert report["simulation_processes"] == 2 and "simulations ran 2 at a time" in md
        # Joint2Coarse beside the ground-truth renders, the baselines (then the ground-truth
        # sets) beside our renderer, the videos (then some of the evaluation's motions) beside
        # the rest of the evaluation, in a second process; their stages keep their names and
        # the stage table has them.
        beside = report["stages_beside"]
        assert beside[0] == "joint2coarse" and beside[1] == "baselines (pix2pix, dnr, dnr-gan)"
        videos = beside.index("videos (ground truth | neural render)")
        assert beside[videos + 1 :] and all(
            n.startswith("evaluation of ") for n in beside[videos + 1 :]
        )
        assert len([n for n in names if n.startswith("evaluation of ")]) > len(beside[videos + 1 :])
        assert "ran in a second process beside" in md
        assert names.index("joint2coarse") > names.index("dataset (ground-truth renders)")
        assert names.index(beside[1]) > names.index("joint2coarse")
        assert names.index(beside[videos]) > names.index(beside[1])
    # Every ground-truth set ran once, in one lane or the other, before the evaluation.
    sets = [n for n in names if n.startswith(("validation set ", "test set "))]
    assert len(sets) == 4 and sets[0].startswith("validation set val-walk")
    assert max(map(names.index, sets)) < names.index(next(n for n in names if "evaluation" in n))


def test_time_left_follows_the_pace_of_the_stages_that_ran():
    import io

    from pipeline.demo import _Progress

    now = [0.0]

    def work(seconds):
        def run():
            now[0] += seconds
            return seconds

        return run

    log = io.StringIO()
    progress = _Progress([10.0, 30.0, 60.0, 100.0], out=log, clock=lambda: now[0])
    progress.stage("reused", work(0.5))  # under a tenth of its cost: sets no pace
    progress.stage("a", work(60.0))  # twice the expected 30 s
    progress.stage("b", work(120.0))
    assert progress.seconds_left() == pytest.approx(2.0 * 100.0)
    assert progress.stage("c", work(1.0)) == 1.0
    lines = log.getvalue().splitlines()
    assert lines[0] == "[1/4] reused (0.0 min in, about 3.3 min left)"  # nominal pace at first
    assert lines[1] == "[2/4] a (0.0 min in, about 3.2 min left)"
    assert lines[3] == "[4/4] c (3.0 min in, about 3.3 min left)"
    assert progress.stage_times == {"reused": 0.5, "a": 60.0, "b": 120.0, "c": 1.0}


def test_rerun_reuses_every_stage(smoke):
    from pipeline.demo import run_demo

    out, _ = smoke
    again = run_demo(PRESETS["smoke"], out, preset_name="smoke")
    assert max(again["stage_seconds"].values()) < 5.0, again["stage_seconds"]


def test_dataset_samples_match_the_renderer_contract(smoke):
    from training.dataset import SAMPLE_KEYS, GarmentDataset

    out, _ = smoke
    for source in ("sim", "joint2coarse"):
        data = GarmentDataset(out, source=source)
        size = PRESETS["smoke"].image_size
        assert len(data) == len(json.loads((out / "dataset/samples.json").read_text())["samples"])
        s = data[0]
        assert set(s) == set(SAMPLE_KEYS)
        channels = {"uv": 2, "motion": 95, "proxy_mask": 1, "target": 3, "background": 3}
        for key, c in {**channels, "target_mask": 1, "proxy_shading": 1}.items():
            assert tuple(s[key].shape) == (3, c, size, size), key
            assert np.isfinite(s[key].numpy()).all()
        assert 0 <= s["target"].min() and s["target"].max() <= 1
        covered = s["proxy_mask"].numpy()[:, 0] > 0
        assert covered.all(axis=(1, 2)).sum() == 0 and covered.any(axis=(1, 2)).all()
        for j in range(3):  # maps are zero off the proxy in each frame
            off = ~covered[j]
            assert (s["uv"].numpy()[j][:, off] == 0).all() and (
                s["motion"].numpy()[j][:, off] == 0
            ).all()
        shade = s["proxy_shading"].numpy()[:, 0]
        assert (shade[~covered] == 0).all() and (shade[covered] >= 0.2 - 1e-6).all()
        assert shade.max() <= 1.0
        # The garment is in the ground truth and absent from the body-only background.
        garment = s["target_mask"].numpy()[:, 0] > 0.5
        diff = np.abs(s["target"].numpy() - s["background"].numpy()).sum(1)
        assert garment.any() and diff[garment].mean() > 0.05


def test_motion_per_vertex_is_the_same_data(smoke, tmp_path):
    """What a trainer on a GPU loads (training.loader.for_device): the same samples with the
    motion features per vertex; interpolated, they are the loader's map, and training on them
    logs the same losses."""
    import torch

    from tests.conftest import assert_close
    from training.dataset import VERTEX_MOTION_SAMPLE_KEYS, GarmentDataset
    from training.loader import for_device
    from training.renderer import PRESETS as RENDERER_PRESETS
    from training.renderer.data import RenderBatch
    from training.renderer.train import collate_samples, train_renderer

    out, _ = smoke
    data = GarmentDataset(out, source="sim")
    assert for_device(data, "cpu") is data
    per_vertex = for_device(data, "cuda")  # a copy: no GPU needed to make it
    assert per_vertex.motion_per_vertex and not data.motion_per_vertex
    for i in (0, len(data) - 1):
        dense, compact = data[i], per_vertex[i]
        assert set(compact) == set(dense) - {"motion"} | set(VERTEX_MOTION_SAMPLE_KEYS)
        assert all(torch.equal(compact[k], dense[k]) for k in dense if k != "motion")
        batch = RenderBatch.from_dict(compact)
        for j in range(3):
            assert_close(batch.motion_frame(j)[0], dense["motion"][j], atol=1e-6)
    collate_samples([per_vertex[0], per_vertex[1]], 95)  # checks the batch
    cfg = RENDERER_PRESETS["tiny"].replace(image_size=PRESETS["smoke"].image_size, steps=3)
    logs = [
        train_renderer(d, tmp_path / name, cfg, progress=False).log_path.read_text()
        for name, d in (("dense", data), ("per-vertex", per_vertex))
    ]
    rows = [[line.split(",") for line in log.splitlines()] for log in logs]
    header = rows[0][0]
    assert header == rows[1][0] and len(rows[0]) == len(rows[1]) > 1
    losses = [c for c, name in enumerate(header) if name not in ("seconds", "step", "epoch")]
    for a, b in zip(rows[0][1:], rows[1][1:], strict=True):  # every column but the wall time
        assert a[: losses[0]] == b[: losses[0]]
        for c in losses:
            if a[c] in ("", "off"):
                assert a[c] == b[c], (header[c], a, b)
            else:
                assert np.isclose(float(a[c]), float(b[c]), rtol=1e-4, atol=1e-6), (header[c], a, b)


def test_renderer_stage_trains_and_reports(smoke):
    from training.csvlog import read_loss_log
    from training.renderer.train import load_model

    out, report = smoke
    r = report["renderer"]
    assert r["steps"] == PRESETS["smoke"].renderer_steps and r["skipped_steps"] == 0
    assert r["source"] == PRESETS["smoke"].renderer_source == "joint2coarse" and r["samples"] > 0
    config, net, disc = load_model(out / "renderer" / "renderer.pt")
    assert config.image_size == PRESETS["smoke"].image_size and disc is not None
    rows = read_loss_log(out / "renderer" / "renderer_loss.csv")
    assert rows[-1]["step"] == r["steps"] and all(np.isfinite(row["l1"]) for row in rows)
    assert "perceptual" not in rows[0]  # off without VGG weights: logged as "off", not a number
    assert (out / "renderer" / "loss.png").stat().st_size > 1000
    assert list((out / "renderer" / "previews").glob("step_*.png"))


def test_test_sets_come_from_unseen_cameras(smoke, tmp_path):
    import torch

    from training.dataset import GarmentDataset

    out, _ = smoke
    train = json.loads((out / "dataset" / "samples.json").read_text())["samples"]
    train_cams = {json.dumps(s["camera"]["extrinsic"]) for s in train}
    for name in ("twirl", "cmu-01_01"):
        index = json.loads((out / "testset" / name / "samples.json").read_text())
        assert index["motion"] == name and index["samples"]
        assert not train_cams & {json.dumps(s["camera"]["extrinsic"]) for s in index["samples"]}
        data = GarmentDataset(out, source="joint2coarse", split=name)
        s = data[0]
        one = GarmentDataset(out, source="joint2coarse", split=name, threads=1)[0]
        assert all(torch.equal(s[k], one[k]) for k in s)  # one ray-casting thread, same maps
        assert s["target"].shape[-1] == PRESETS["smoke"].image_size
        assert s["proxy_mask"].sum() > 0 and s["target_mask"].sum() > 0
    with pytest.raises(InputError, match="run the testset stage first"):
        GarmentDataset(out, split="walk")
    # one mapping from a proxy source to its file, for the data set and the stages alike
    with pytest.raises(InputError, match="source must be 'sim' or 'joint2coarse', got 'nope'"):
        GarmentDataset(out, source="nope")
    alone = tmp_path / "index-only" / "testset" / "twirl"  # a test set without its proxies
    alone.mkdir(parents=True)
    (alone / "samples.json").write_bytes((out / "testset" / "twirl" / "samples.json").read_bytes())
    with pytest.raises(InputError, match="no Joint2Coarse prediction of twirl") as err:
        GarmentDataset(alone.parents[1], source="joint2coarse", split="twirl")
    assert "joint2coarse/pred-twirl.npz" in str(err.value)


def test_print_config_shows_the_resolved_settings_and_changes_nothing(smoke, capsys):
    from app.cli import main

    out, report = smoke
    before = (out / "project.json").read_bytes()
    assert main(["train", "renderer", str(out), "--print-config", "--set", "w_gan=0.3"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == {**report["renderer"]["config"], "w_gan": 0.3}  # what the report shows
    assert main(["train", "baselines", str(out), "--print-config"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert set(printed) == set(PRESETS["smoke"].baselines)
    assert printed["dnr"] == report["baselines"]["dnr"]["config"]
    assert main(["train", "joint2coarse", str(out), "--print-config"]) == 0
    assert json.loads(capsys.readouterr().out)["model"] == report["joint2coarse"]["model"]
    assert (out / "project.json").read_bytes() == before  # nothing saved, nothing trained


def test_train_renderer_cli_with_new_settings(smoke, tmp_path):
    import shutil

    out, _ = smoke
    copy = tmp_path / "project"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("finetune", "baselines", "eval"))
    dng = [sys.executable, "-m", "app.cli", "train", "renderer", str(copy)]
    r = subprocess.run(dng + ["--steps", "12"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    report = json.loads((copy / "renderer" / "report.json").read_text())
    assert report["steps"] == 12 and report["resumed_at_step"] == 0  # the old checkpoint is stale
    assert project_config(Project(copy)).renderer_steps == 12  # saved for dng eval and the GUI
    r = subprocess.run(dng + ["--preset", "huge"], capture_output=True, text=True)
    assert r.returncode == 2 and "unknown renderer preset 'huge'" in r.stderr

    r = subprocess.run(
        dng + ["--steps", "6", "--set", "w_gan=0", "--set", "w_fm=0"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    config = project_config(Project(copy))
    assert config.renderer_overrides == {"w_gan": 0, "w_fm": 0}
    report = json.loads((copy / "renderer" / "report.json").read_text())
    assert report["config"]["w_gan"] == 0 and report["config"]["w_fm"] == 0
    assert report["steps"] == 6 and report["resumed_at_step"] == 0  # new settings: a new run
    for bad, message in (
        ("w_gann=0", "unknown renderer config keys ['w_gann']"),
        ("w_gan=-1", "w_gan=-1 must be a finite number >= 0"),
        ("w_gan", "--set expects KEY=VALUE"),
    ):
        r = subprocess.run(dng + ["--set", bad], capture_output=True, text=True)
        assert r.returncode == 2 and message in r.stderr, (bad, r.stderr)
    assert project_config(Project(copy)).renderer_overrides["w_gan"] == 0  # refused: unchanged

    base = [sys.executable, "-m", "app.cli", "train", "baselines", str(copy), "--kinds", "dnr"]
    r = subprocess.run(base + ["--set", "lr_decay_from=1.5"], capture_output=True, text=True)
    assert r.returncode == 2 and "lr_decay_from=1.5 must be a number in [0, 1]" in r.stderr
    r = subprocess.run(base + ["--set", "lr_decay_from=0.5"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert project_config(Project(copy)).baseline_overrides == {"lr_decay_from": 0.5}
    report = json.loads((copy / "baselines" / "dnr" / "report.json").read_text())
    assert report["config"]["lr_decay_from"] == 0.5 and report["steps"] == 6

    j2c = [sys.executable, "-m", "app.cli", "train", "joint2coarse", str(copy)]
    r = subprocess.run(j2c + ["--set", "dropuot=0.2"], capture_output=True, text=True)
    assert r.returncode == 2 and "unknown joint2coarse config keys ['dropuot']" in r.stderr
    r = subprocess.run(j2c + ["--set", "dropout=0.2"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert project_config(Project(copy)).joint2coarse_overrides == {"dropout": 0.2}
    report = json.loads((copy / "joint2coarse" / "report.json").read_text())
    assert report["config"]["dropout"] == 0.2


def test_cli_commands_on_the_project(smoke, tmp_path, bvh_dir):
    out, _ = smoke
    dng = [sys.executable, "-m", "app.cli"]
    pred = tmp_path / "pred.pc2"
    r = subprocess.run(
        dng
        + [
            "predict",
            "proxy",
            str(out),
            "--motion",
            str(bvh_dir / "01_03.bvh"),
            "--out",
            str(pred),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    assert pred.stat().st_size > 1000
    sheet = tmp_path / "sheet.png"
    r = subprocess.run(
        dng + ["dataset", str(out), "--sheet", str(sheet)], capture_output=True, text=True
    )
    assert r.returncode == 0 and sheet.stat().st_size > 1000, r.stderr
    r = subprocess.run(
        dng + ["train", "joint2coarse", str(tmp_path)], capture_output=True, text=True
    )
    assert r.returncode == 2 and "not a garment project" in r.stderr
    assert r.stderr.count("\n") == 1


def test_settings_round_trip_and_errors(tmp_path):
    for name, cfg in PRESETS.items():
        assert PipelineConfig.from_params(json.loads(json.dumps(cfg.as_params()))) == cfg, name
    with pytest.raises(InputError, match="unknown preset"):
        preset("huge")
    proj = Project(tmp_path)
    proj.save_settings({"pipeline": {"garment": "x"}})
    with pytest.raises(InputError, match="project.json: malformed pipeline settings"):
        project_config(proj)
    from dataclasses import replace

    for name, bad in (("torch_threads", 0), ("raster_threads", -1), ("loader_workers", 1.5)):
        with pytest.raises(InputError, match=f"{name} must be an integer >= "):
            replace(preset("quick"), **{name: bad})


def test_overrides_reach_their_network_and_dnr_with_our_loss():
    from dataclasses import replace

    from pipeline.config import baseline_config, joint2coarse_config, renderer_config

    quick = preset("quick")
    ours = renderer_config(quick)
    assert (ours.w_l1, ours.w_fm, ours.w_gan) == (10.0, 0.0, 0.0)  # chosen on validation
    assert quick.baselines == ("pix2pix", "dnr")  # DNR with our loss would be DNR itself
    adversarial = replace(quick, renderer_overrides={"w_fm": 1.0, "w_gan": 0.1})
    gan = baseline_config(adversarial, "dnr-gan")
    assert (gan.w_l1, gan.w_perceptual, gan.w_fm, gan.w_gan) == (10.0, 10.0, 1.0, 0.1)
    assert baseline_config(quick, "dnr").w_gan == 0.0  # L1 only, as the paper's DNR
    assert baseline_config(quick, "pix2pix").w_gan == 1.0  # its own loss
    for kind in ("pix2pix", "dnr", "dnr-gan"):  # every baseline on our optimiser schedule
        b = baseline_config(quick, kind)
        assert (b.lr_g, b.lr_decay_from) == (ours.lr_g, ours.lr_decay_from)
    fast_texels = replace(quick, renderer_overrides={"texture_lr_scale": 10.0})
    assert baseline_config(fast_texels, "dnr").texture_lr_scale == 10.0  # ours' texture's rate
    listed = replace(quick, renderer_overrides={"texture_sizes": [64, 32], "steps": 7})
    cfg = renderer_config(listed)
    assert cfg.texture_sizes == (64, 32) and cfg.steps == 7  # JSON lists become tuples
    assert baseline_config(listed, "dnr").steps == 7  # the baselines train as many steps
    with pytest.raises(InputError, match=r"unknown renderer config keys \['w_gann'\]"):
        renderer_config(replace(quick, renderer_overrides={"w_gann": 0}))
    with pytest.raises(InputError, match="w_gan=-1 must be a finite number"):
        renderer_config(replace(quick, renderer_overrides={"w_gan": -1}))
    j2c = joint2coarse_config(replace(quick, joint2coarse_overrides={"encoder_widths": [64, 32]}))
    assert j2c.encoder_widths == (64, 32) and j2c.dropout == 0.05
    with pytest.raises(InputError, match="dropout=1.5 must be in"):
        joint2coarse_config(replace(quick, joint2coarse_overrides={"dropout": 1.5}))


def test_a_new_ground_truth_reruns_what_learned_from_the_old_one(smoke, tmp_path):
    """The renderer, the baselines and the evaluation take ``samples.json`` as their input; it
    names the target cache's hash, so new target motion with the same cameras still reruns them."""
    import shutil
    from dataclasses import replace

    from core.sim import load_cache, save_cache
    from pipeline.stages.dataset import stage_dataset

    out, _ = smoke
    copy = tmp_path / "project"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("baselines", "eval", "videos"))
    index = copy / "dataset" / "samples.json"
    before = json.loads(index.read_text())
    target = copy / "sim" / "dance-target" / "cache.npz"
    cache = load_cache(target)
    save_cache(target, replace(cache, positions=cache.positions + np.float32(0.01)))
    project = Project(copy)
    stage_dataset(project, project_config(project))
    after = json.loads(index.read_text())
    assert after["samples"] == before["samples"]  # the same cameras ...
    assert after["ground_truth"] != before["ground_truth"]  # ... of another ground truth


def test_the_proxy_solver_setting_reaches_the_proxy_simulation(smoke, tmp_path):
    """``sim_solver`` and its tolerance go to every proxy simulation of the project (the quick
    preset's ground truth is the implicit solver's); settings saved before the setting existed
    mean Style3D, as they were made."""
    import shutil
    from dataclasses import replace

    from core.sim import load_cache
    from pipeline.config import sim_config
    from pipeline.stages.simulate import stage_simulate

    quick = sim_config(PRESETS["quick"])
    assert (quick.solver, quick.substeps, quick.implicit_norm) == ("implicit", 2, "rms")
    older = {k: v for k, v in PRESETS["smoke"].as_params().items() if not k.startswith("sim_")}
    assert sim_config(PipelineConfig.from_params(older)).solver == "style3d"
    out, _ = smoke
    copy = tmp_path / "project"
    copy.mkdir()
    for part in ("project.json", "motions", "garment", "proxy"):
        (shutil.copytree if (out / part).is_dir() else shutil.copy)(out / part, copy / part)
    project = Project(copy)
    config = replace(
        project_config(project), sim_solver="implicit", sim_substeps=2, sim_implicit_tol=3e-4,
        sim_implicit_norm="rms",
    )  # fmt: skip
    cache = load_cache(stage_simulate(project, config, "twirl", "proxy"))
    assert cache.params["solver"] == "core.sim.implicit.ImplicitCloth"
    assert cache.params["sim"]["implicit_norm"] == "rms" and np.isfinite(cache.positions).all()
    report = json.loads((copy / "sim" / "twirl-proxy" / "report.json").read_text())
    assert report["steps_per_frame"] == 2 and report["strain_max"] < report["strain_limit"] * 1.5


def test_a_project_under_another_light_renders_its_data_set_under_it(smoke, tmp_path):
    """``PipelineConfig.lighting``: the data set is rendered again under the project's light,
    and the studio's light leaves a project's stages as they were."""
    import shutil
    from dataclasses import replace

    from PIL import Image

    from core.lighting import PRESETS as LIGHTS
    from pipeline.stages.dataset import lighting_params, project_shading, stage_dataset

    out, _ = smoke
    copy = tmp_path / "project"
    keep = ("motions", "garment", "proxy", "sim", "dataset", "embedding", "project.json")
    shutil.copytree(
        out, copy, ignore=lambda d, names: [n for n in names if d == str(out) and n not in keep]
    )
    config = project_config(Project(copy))
    assert config.lighting == "studio" and lighting_params(config) == {}
    assert project_shading(config).lighting == LIGHTS["studio"]
    first = sorted((copy / "dataset" / "samples").glob("*_image.png"))[0]
    studio = np.asarray(Image.open(first), dtype=int)
    stage_dataset(Project(copy), replace(config, lighting="overcast"))
    overcast = np.asarray(Image.open(first), dtype=int)
    assert np.abs(overcast - studio).sum(-1).mean() > 10
    bad = replace(config, lighting=str(tmp_path / "none.hdr"))
    with pytest.raises(InputError, match="none.hdr"):
        stage_dataset(Project(copy), bad)
