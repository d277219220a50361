"""``dng bench trade`` (speed/accuracy on a trained project) and ``dng bench all``."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


# ------------------------------------------------------------------------- pieces


def test_pareto_front_and_widths():
    from app.bench.trade import pareto_front, parse_widths
    from core.errors import InputError

    pts = [(10.0, 20.0), (5.0, 18.0), (20.0, 19.0), (40.0, 25.0), (5.0, 17.0)]
    assert pareto_front(pts) == [1, 0, 3]  # (20, 19) and (5, 17) are beaten
    assert parse_widths(["8/64", "16/128"]) == [(8, 64), (16, 128)]
    for bad in ("16", "a/b", "64/8", "0/8"):
        with pytest.raises(InputError):
            parse_widths([bad])


def test_resized_dataset_and_upsampled_renderer(smoke_project):
    from app.bench.trade import ResizedDataset, UpsampledRenderer
    from core.errors import InputError
    from training.dataset import GarmentDataset
    from training.renderer import RenderNet, preset

    data = GarmentDataset(smoke_project, source="joint2coarse", split="twirl")
    full = data[0]
    size = full["target"].shape[-1]
    low = ResizedDataset(data, size // 2)[0]
    assert set(low) == set(full)
    for k, v in low.items():
        assert v.shape == (*full[k].shape[:2], size // 2, size // 2), k
        assert torch.isfinite(v).all(), k
    # Images are area-averaged: one low pixel is the mean of its 2 x 2 block.
    block = full["target"][..., :2, :2].mean(dim=(-1, -2))
    np.testing.assert_allclose(low["target"][..., 0, 0], block, atol=1e-6)
    # Maps are rasterized from the rescaled camera: the proxy covers about the same fraction.
    cover_full = full["proxy_mask"][1].mean().item()
    assert abs(low["proxy_mask"][1].mean().item() - cover_full) < 0.1 * cover_full + 0.02
    both = ResizedDataset(data, size // 2, keep_full=True)[0]
    assert both["target"].shape == full["target"].shape
    assert both["lo_uv"].shape == low["uv"].shape
    same = ResizedDataset(data, size)[0]
    assert torch.equal(same["motion"], full["motion"])
    with pytest.raises(InputError, match="only downsamples"):
        ResizedDataset(data, 2 * size)

    net = RenderNet(preset("tiny").replace(image_size=size // 2))
    batch = torch.utils.data.default_collate([both])
    out = UpsampledRenderer(net).render(batch)
    assert out.shape == (1, 3, size, size)


def test_trade_bad_project_exits_2(tmp_path, dng):
    missing = tmp_path / "no-such-project"
    code, _, err = dng("bench", "trade", "--project", missing, "--out", tmp_path / "o")
    assert code == 2
    assert str(missing) in err and "not found" in err

    from pipeline.config import PRESETS

    half = tmp_path / "half"  # a project with settings but nothing trained
    half.mkdir()
    (half / "project.json").write_text(
        json.dumps({"preset": "smoke", "pipeline": PRESETS["smoke"].as_params()})
    )
    code, _, err = dng("bench", "trade", "--project", half, "--out", tmp_path / "o")
    assert code == 2 and str(half / "dataset") in err
    assert not (tmp_path / "o").exists()


def test_trade_rejects_sizes_above_the_project(smoke_project, tmp_path, dng):
    code, _, err = dng(
        "bench", "trade", "--project", smoke_project, "--out", tmp_path / "o",
        "--sizes", 128, "--steps", 1,
    )  # fmt: skip
    assert code == 2 and "only downsamples" in err
    code, _, err = dng(
        "bench", "trade", "--project", smoke_project, "--out", tmp_path / "o",
        "--motion", "nope",
    )  # fmt: skip
    assert code == 2 and "no test set for motion 'nope'" in err


# ------------------------------------------------------------------------- the bench


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v)


@pytest.mark.slow
def test_trade_on_smoke_project(smoke_project, tmp_path, dng):
    """Two sizes x one width, a few steps, one proxy size, a 3-frame simulation (~2 min)."""
    before = sorted(p.relative_to(smoke_project) for p in smoke_project.rglob("*"))
    out = tmp_path / "trade"
    code, text, err = dng(
        "bench", "trade", "--project", smoke_project, "--out", out, "--steps", 3,
        "--sizes", 64, 32, "--widths", "8/16", "--proxy-sizes", 300, "--sim-frames", 3,
        "--frames", 2,
    )  # fmt: skip
    assert code == 0, err
    assert "load average" in text and "ratio" in text
    table = json.loads((out / "trade.json").read_text())
    assert (out / "trade.png").stat().st_size > 1000
    assert [r["label"] for r in table["rows"]] == ["64px 8/16", "32px 8/16"]
    for r in table["rows"]:
        for key in (
            "frame_ms", "fps", "joint2coarse_ms", "raster_feat_ms", "network_ms", "psnr", "ssim",
            "mse", "psnr_native", "seconds_per_step", "train_peak_rss_mib", "infer_peak_rss_mib",
        ):  # fmt: skip
            assert _finite(r[key]), (r["label"], key, r[key])
        assert r["frame_ms"] > 0 and 0 < r["ssim"] <= 1 and r["train_peak_rss_mib"] > 50
        assert r["steps"] == 3 and r["test_samples"] > 0
    full, half = table["rows"]
    assert full["psnr"] == full["psnr_native"]  # at the project's size the two agree
    assert table["pareto"] and set(table["pareto"]) <= {r["label"] for r in table["rows"]}
    (p,) = table["proxy_rows"]
    assert p["target_verts"] == 300 and _finite(p["frame_ms"]) and 0 < p["hausdorff_rel"] < 1
    vs = table["neural_vs_simulation"]
    assert "error" not in vs["simulation"], vs["simulation"]
    assert vs["simulation"]["setting"] == vs["simulation"]["attempts"][-1]["setting"]
    assert _finite(vs["ratio"]) and vs["ratio"] > 0
    assert vs["neural"]["frame_ms"] > 0 and vs["simulation"]["ms_per_frame"] > 0
    assert _finite(vs["simulation"]["peak_rss_mib"])
    assert len(table["load_average_before"]) == 3
    # Nothing written into the project: the renderers live under --out.
    assert sorted(p.relative_to(smoke_project) for p in smoke_project.rglob("*")) == before
    assert (out / "runs" / "32px-8x16" / "renderer.pt").is_file()


def test_trade_quick_run_without_proxy_and_simulation(smoke_project, tmp_path, dng):
    """One setting, two steps, no proxy axis, no simulation: the table, JSON and plot."""
    out = tmp_path / "trade"
    code, text, err = dng(
        "bench", "trade", "--project", smoke_project, "--out", out, "--steps", 2,
        "--sizes", 32, "--widths", "8/16", "--proxy-sizes", "--sim-frames", 0, "--frames", 1,
        "--json",
    )  # fmt: skip
    assert code == 0, err
    table = json.loads(text)
    assert table == json.loads((out / "trade.json").read_text())
    (row,) = table["rows"]
    assert row["size"] == 32 and _finite(row["psnr"]) and _finite(row["psnr_native"])
    assert row["psnr"] != row["psnr_native"]  # scored at 64 px (upsampled) and at 32 px
    assert table["proxy_rows"] == [] and table["neural_vs_simulation"] is None
    assert (out / "trade.png").is_file()


# ------------------------------------------------------------------------- bench all


def _fake(name, code=0, error=None):
    def add_arguments(parser):
        from app.bench import add_output_arguments

        add_output_arguments(parser)
        if name in ("trade", "placement"):
            parser.add_argument("--project", required=True)
        parser.add_argument("--level", type=int, default=3)

    def run_bench(args):
        if error:
            raise error
        from pathlib import Path

        Path(args.out).mkdir(parents=True, exist_ok=True)
        (Path(args.out) / "args.json").write_text(json.dumps(vars(args)))
        print(f"{name} table")
        return code

    return SimpleNamespace(__name__=f"app.bench.{name}", add_arguments=add_arguments, run=run_bench)


def test_bench_all_runs_each_with_defaults(tmp_path, dng, monkeypatch):
    from app.bench import all as bench_all
    from core.errors import InputError

    fakes = {
        "proxy": _fake("proxy"),
        "sim": _fake("sim", error=InputError("bad garment", "/x.obj")),
        "raster": _fake("raster", error=RuntimeError("boom")),
        "render": _fake("render", code=0),
        "train": _fake("train"),
        "trade": _fake("trade"),
        "placement": _fake("placement"),
    }
    monkeypatch.setattr(bench_all, "load_benches", lambda names: {n: fakes[n] for n in names})
    out = tmp_path / "all"
    code, text, err = dng("bench", "all", "--out", out, "--json")
    assert code == 1  # two benches failed
    summary = json.loads(text)  # stdout holds only the summary
    assert summary == json.loads((out / "all.json").read_text())
    by = {r["bench"]: r for r in summary["benches"]}
    assert list(by) == ["proxy", "sim", "raster", "render", "train", "trade", "placement"]
    assert by["proxy"]["ran"] and by["proxy"]["exit_code"] == 0 and by["proxy"]["seconds"] >= 0
    assert by["sim"]["exit_code"] == 2 and "bad garment" in by["sim"]["error"]
    assert by["raster"]["exit_code"] == 1 and "boom" in by["raster"]["error"]
    assert not by["trade"]["ran"] and "project" in by["trade"]["skipped"]
    assert not by["placement"]["ran"] and "project" in by["placement"]["skipped"]
    args = json.loads((out / "proxy" / "args.json").read_text())
    assert args == {"out": str(out / "proxy"), "json": False, "level": 3}
    assert "proxy table" in err  # the benches' own tables went to stderr

    code, text, _ = dng(
        "bench", "all", "--out", out, "--project", tmp_path, "--only", "trade", "proxy"
    )
    assert code == 0
    summary = json.loads((out / "all.json").read_text())
    assert [r["bench"] for r in summary["benches"]] == ["proxy", "trade"]
    args = json.loads((out / "trade" / "args.json").read_text())
    assert args["project"] == str(tmp_path) and args["out"] == str(out / "trade")
    assert "trade: exit 0" in text

    code, _, err = dng("bench", "all", "--out", out, "--only", "nope")
    assert code == 2 and "unknown bench" in err
