"""``benchmarks/renderer_regions.py``: a method's garment-region error split by what each pixel
holds, on cases with known answers."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from tests.conftest import load_benchmark

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "renderer_regions.py"


def _bench():
    return load_benchmark("renderer_regions.py")


def _scene(size: int, garment_box, proxy_box, body_column: int | None = None) -> dict:
    """One size x size sample (frames t-1, t, t+1 alike): a red garment in the (rows, columns)
    slices ``garment_box`` over a 0.5 grey backdrop, the proxy in ``proxy_box``, and the body
    in column ``body_column`` of the backdrop."""
    bg = torch.full((3, size, size), 0.5)
    if body_column is not None:
        bg[:, :, body_column] = torch.tensor([0.9, 0.7, 0.6])[:, None]
    garment = torch.zeros(1, size, size)
    garment[0][garment_box] = 1
    proxy = torch.zeros(1, size, size)
    proxy[0][proxy_box] = 1
    target = torch.where(garment.bool(), torch.tensor([0.8, 0.1, 0.1])[:, None, None], bg)
    frames = lambda a: torch.stack([a, a, a])  # noqa: E731
    return {
        "target": frames(target),
        "background": frames(bg),
        "target_mask": frames(garment),
        "proxy_mask": frames(proxy),
    }


def _sample() -> dict:
    """4 x 4: the body in column 3, the garment in rows 1-2 of columns 0-2, the proxy in rows
    1-3 of columns 1-3. So frame t has 4 px of garment on the proxy over the backdrop, 2 px of
    garment off the proxy, and 5 px of proxy alone: 3 over the body, 2 over the backdrop."""
    return _scene(4, (slice(1, 3), slice(0, 3)), (slice(1, 4), slice(1, 4)), body_column=3)


class _Paints:
    def __init__(self, fn):
        self.fn = fn

    def render(self, batch):
        return self.fn(batch)


def test_the_categories_partition_the_garment_region_and_add_up_to_the_mse():
    bench = _bench()
    data = [_sample(), _sample()]
    models = {
        "truth": _Paints(lambda b: b["target"][:, 1]),
        "background": _Paints(lambda b: b["background"][:, 1]),
        "grey": _Paints(lambda b: torch.full_like(b["target"][:, 1], 0.5)),
    }
    out = bench.split_error(models, data, batch_size=1)
    share = out["share"]
    # garment 6 px, proxy 9 px, both 4 px: 11 px of garment region a sample
    assert out["pixels"] == 22
    assert abs(sum(share.values()) - 1) < 1e-12
    assert abs(share["garment on the proxy, backdrop behind"] - 4 / 11) < 1e-12
    assert share["garment on the proxy, body behind"] == 0
    assert abs(share["garment off the proxy"] - 2 / 11) < 1e-12
    assert abs(share["proxy only, body shows"] - 3 / 11) < 1e-12
    assert abs(share["proxy only, backdrop shows"] - 2 / 11) < 1e-12
    # the ground truth has no error anywhere
    assert all(v == 0 for v in out["methods"]["truth"].values())
    # the background is wrong only where the garment is, by the garment's distance from it
    back = out["methods"]["background"]
    assert back["proxy only, backdrop shows"] == back["proxy only, body shows"] == 0
    on_backdrop = ((0.8 - 0.5) ** 2 + 2 * (0.1 - 0.5) ** 2) / 3
    assert abs(back["garment on the proxy, backdrop behind"] - on_backdrop * 4 / 11) < 1e-6
    # every method's categories add up to its pixel-pooled garment-region MSE
    for name, row in out["methods"].items():
        pooled = sum(v for k, v in row.items() if k != "total")
        assert abs(row["total"] - pooled) < 1e-12, name
    # a flat grey misses the garment off the proxy as on it, and the body where it shows
    grey = out["methods"]["grey"]
    assert abs(grey["garment off the proxy"] - on_backdrop * 2 / 11) < 1e-6
    body = ((0.9 - 0.5) ** 2 + (0.7 - 0.5) ** 2 + (0.6 - 0.5) ** 2) / 3
    assert abs(grey["proxy only, body shows"] - body * 3 / 11) < 1e-6
    assert grey["proxy only, backdrop shows"] == 0


def test_a_missing_model_file_exits_2_naming_it(smoke_project):
    run = subprocess.run(
        [sys.executable, str(BENCH), str(smoke_project), "--model", "x=/no/such/model.pt"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert run.returncode == 2 and "/no/such/model.pt" in run.stderr
    assert "model file not found" in run.stderr


def _block_sample() -> dict:
    """10 x 10: the garment in rows 2-7, columns 2-7; the proxy in rows 2-8, columns 1-8 (a
    pixel wider than the garment on three sides); no body."""
    return _scene(10, (slice(2, 8), slice(2, 8)), (slice(2, 9), slice(1, 9)))


def test_the_gms_split_finds_missed_edges_and_edges_that_are_not_there():
    bench = _bench()
    data = [_block_sample(), _block_sample()]

    def scratched(b):  # the truth, with a dark line across the garment's flat middle
        out = b["target"][:, 1].clone()
        out[:, :, 4, 3:7] = 0.0
        return out

    models = {
        "truth": _Paints(lambda b: b["target"][:, 1]),
        "background": _Paints(lambda b: b["background"][:, 1]),
        "scratched": _Paints(scratched),
    }
    out = bench.split_gms(models, data, batch_size=1)
    assert abs(sum(out["share"].values()) - 1) < 1e-12
    assert out["share"]["edge, on the proxy"] > 0 and out["share"]["flat, on the proxy"] > 0
    assert out["share"]["edge, off the proxy"] == 0  # the proxy covers the garment's edges
    for name, row in out["methods"].items():
        parts = sum(row[c] for c in bench.GMS_CATEGORIES)
        assert abs(row["total"] - parts) < 1e-12, name
    truth = out["methods"]["truth"]
    assert all(abs(v) < 1e-12 for v in truth.values())
    # the bare backdrop misses every edge, and is flat where the garment is flat
    back = out["methods"]["background"]
    assert back["edge, on the proxy"] > 0.1 and back["flat, on the proxy"] == 0
    assert back["gmsd"] > 0
    # a line where the ground truth is flat: a deficit on the flat part
    scratch = out["methods"]["scratched"]
    assert scratch["flat, on the proxy"] > 0 and scratch["gmsd"] > 0


def test_the_blur_scores_know_the_truth_its_blur_and_its_shift():
    """The ground truth scores 0 on every edge measure and detail 1; blurred, its detail falls
    and its mean deficit and MSE rise with the blur; moved a pixel, its detail stays and its
    edges are missed; each method's row is beside its blurred rows."""
    bench = _bench()
    data = [_block_sample(), _block_sample()]
    models = {"truth": _Paints(lambda b: b["target"][:, 1])}
    rows = bench.blur_scores(models, data, sigmas=(0.7, 1.5), batch_size=1)["rows"]
    assert list(rows) == [
        "truth", "truth, blurred 0.7 px", "truth, blurred 1.5 px",
        "ground truth, blurred 0.7 px", "ground truth, blurred 1.5 px",
        "ground truth, a pixel to the right",
    ]  # fmt: skip
    t = rows["truth"]
    assert t["gmsd"] == t["gms deficit"] == t["mse"] == 0 and abs(t["detail"] - 1) < 1e-12
    assert rows["truth, blurred 1.5 px"] == rows["ground truth, blurred 1.5 px"]
    light, heavy = rows["ground truth, blurred 0.7 px"], rows["ground truth, blurred 1.5 px"]
    assert 1 > light["detail"] > heavy["detail"]
    assert 0 < light["gms deficit"] < heavy["gms deficit"] and 0 < light["mse"] < heavy["mse"]
    moved = rows["ground truth, a pixel to the right"]
    assert moved["gms deficit"] > 0 and moved["mse"] > 0 and abs(moved["detail"] - 1) < 0.2
    # a blur's image is the same size, in [0, 1], and keeps a flat image flat
    flat = torch.full((1, 3, 6, 6), 0.25)
    assert torch.allclose(bench.blurred(flat, 1.0), flat)


def test_the_dynamics_scores_know_a_still_image_that_is_the_truth_and_one_that_is_not():
    """Embedded images equal to the ground truth: nothing is dynamics, and every method's MSE is
    the same against either. Embedded images that are the bare background: their MSE is the
    background's own, and the background method is exact against them."""
    bench = _bench()
    data = [_block_sample(), _block_sample()]
    models = {
        "truth": _Paints(lambda b: b["target"][:, 1]),
        "background": _Paints(lambda b: b["background"][:, 1]),
    }
    truth = torch.stack([s["target"][1] for s in data])
    same = bench.dynamics_scores(models, data, truth, batch_size=1)
    assert same["embedded"]["mse"] == same["embedded"]["gmsd"] == 0
    for row in same["methods"].values():
        assert abs(row["mse"] - row["mse_to_embedded"]) < 1e-12
    assert same["methods"]["background"]["mse"] > 0
    bare = torch.stack([s["background"][1] for s in data])
    other = bench.dynamics_scores(models, data, bare, batch_size=1)
    back = other["methods"]["background"]
    assert abs(other["embedded"]["mse"] - back["mse"]) < 1e-7 and back["mse_to_embedded"] == 0
    assert abs(other["methods"]["truth"]["mse_to_embedded"] - back["mse"]) < 1e-7
    # the picture: a row for the ground truth, one for the embedded image, one per method
    one = bench.dynamics_sheet({"truth": models["truth"]}, data, bare, samples=2)
    two = bench.dynamics_sheet(models, data, bare, samples=2)
    assert one.dtype == two.dtype == np.uint8 and one.shape[2] == 3
    assert one.shape[1] == two.shape[1] and two.shape[0] > one.shape[0]
    try:
        bench.dynamics_scores(models, data, bare[:1])
    except Exception as exc:  # one image for two samples
        assert "1 embedded images for 2 samples" in str(exc)
    else:
        raise AssertionError("a short stack of embedded images was taken")


def test_on_an_embedded_ground_truth_the_embedded_render_is_the_ground_truth(smoke_project):
    """The smoke preset's target is embedded (no dynamics of its own): the benchmark's embedded
    render of a test motion, from the test set's cameras, is the test set's ground truth."""
    import json

    run = subprocess.run(
        [sys.executable, str(BENCH), str(smoke_project), "--measure", "dynamics", "--json",
         "--motion", _an_evaluated_motion(smoke_project)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out["measure"] == "dynamics" and set(out["methods"]) >= {"ours"}
    assert out["embedded"]["mse"] < 1e-6 and out["embedded"]["gms deficit"] < 1e-3
    for row in out["methods"].values():
        assert abs(row["mse"] - row["mse_to_embedded"]) < 1e-5


def _an_evaluated_motion(project: Path) -> str:
    """A motion with a test set in ``project``."""
    return sorted(p.name for p in (project / "testset").iterdir() if p.is_dir())[0]
