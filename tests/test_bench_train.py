"""``dng bench train``: renderer training speed on synthetic batches of the data set's shapes."""

from __future__ import annotations

import json

import pytest
import torch

from app.bench.train import ShapeDataset
from training.renderer.data import RenderBatch


def test_shape_dataset_per_vertex_samples():
    data = ShapeDataset(2, 16, vertices=50)
    batch = RenderBatch.from_dict(torch.utils.data.default_collate([data[0], data[1]]))
    assert batch.motion is None and batch.vertex_motion.shape == (2, 3, 50, 95)
    assert batch.motion_frame(1).shape == (2, 95, 16, 16)
    weights = batch.motion_weights.sum(2)  # barycentric on the proxy, 0 off it
    assert torch.allclose(weights, batch.proxy_mask[:, :, 0], atol=1e-6)


def test_shape_dataset_makes_valid_samples():
    data = ShapeDataset(3, 16)
    batch = RenderBatch.from_dict(torch.utils.data.default_collate([data[0], data[1]]))
    assert batch.size == (16, 16) and batch.motion.shape == (2, 3, 95, 16, 16)
    assert set(batch.proxy_mask.unique().tolist()) <= {0.0, 1.0}
    # Two distinct samples, made once and served in turn.
    assert data[2]["uv"] is data[0]["uv"] and not torch.equal(data[0]["uv"], data[1]["uv"])
    with pytest.raises(IndexError):
        data[3]


@pytest.mark.parametrize("workers", [0, 1])
def test_bench_train_reports_steps_memory_and_waiting(tmp_path, dng, workers):
    code, out, err = dng(
        "bench", "train", "--preset", "tiny", "--size", 32, "--batch", 2, "--steps", 1,
        "--workers", workers, "--out", tmp_path, "--json",
    )  # fmt: skip
    assert code == 0, err
    (row,) = json.loads(out)["rows"]
    assert row["batch"] == 2 and row["workers"] == workers and row["steps_per_s"] > 0
    assert 0.0 <= row["wait_share"] < 1.0 and row["peak_memory_mib"] > 0
    assert row["torch"] == torch.__version__ and row["data"].startswith("synthetic")
    assert row["motion"] == "pixels"  # auto on the CPU: the loader's map, as the trainers
    assert (tmp_path / "train.json").is_file()


def test_bench_train_bad_arguments(tmp_path, dng):
    code, _, err = dng("bench", "train", "--preset", "tiny", "--size", 30, "--out", tmp_path)
    assert code == 2 and "stride" in err
    code, _, err = dng("bench", "train", "--preset", "nope", "--out", tmp_path)
    assert code == 2 and "nope" in err


@pytest.mark.gpu
def test_bench_train_on_cuda(tmp_path, dng):
    code, out, err = dng(
        "bench", "train", "--device", "cuda", "--preset", "cpu", "--size", 64, "--batch", 2,
        "--steps", 2, "--workers", 1, "--motion", "auto", "pixels", "--out", tmp_path, "--json",
    )  # fmt: skip
    assert code == 0, err
    rows = json.loads(out)["rows"]
    assert [r["motion"] for r in rows] == ["vertices", "pixels"]  # auto: as the trainers on CUDA
    for row in rows:
        assert row["peak_memory_kind"].startswith("cuda") and row["peak_memory_mib"] > 0
