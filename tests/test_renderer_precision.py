"""bfloat16 training of the neural renderer against the float32 reference (on the CPU, where
autocast supports bfloat16 too; the gpu tests repeat the forward on CUDA)."""

from __future__ import annotations

import pytest
import torch

from core.errors import InputError
from training.renderer import PRESETS, SyntheticDataset, synthetic_scene, train_renderer
from training.renderer.config import RendererConfig
from training.renderer.data import RenderBatch
from training.renderer.model import RenderNet

torch.set_num_threads(1)
TINY = PRESETS["tiny"].replace(preview_every=0)


@pytest.fixture(scope="module")
def data():
    return SyntheticDataset(synthetic_scene(6), 32, cameras_per_frame=2, seed=0)


def test_precision_resolves_per_device_and_reads_old_files():
    assert RendererConfig().precision == "auto"
    assert RendererConfig().resolved_precision("cuda") == "bf16"
    assert RendererConfig().resolved_precision("cpu") == "fp32"
    assert RendererConfig(precision="bf16").resolved_precision("cpu") == "bf16"
    with pytest.raises(InputError, match="fp16 needs CUDA"):
        RendererConfig(precision="fp16").resolved_precision("cpu")
    with pytest.raises(InputError, match="precision"):
        RendererConfig(precision="int8")
    old = RendererConfig().to_dict()
    del old["precision"]
    assert RendererConfig.from_dict({**old, "mixed_precision": True}).precision == "auto"
    assert RendererConfig.from_dict({**old, "mixed_precision": False}).precision == "fp32"


def test_bf16_forward_is_close_to_fp32(data):
    torch.manual_seed(0)
    net = RenderNet(TINY).eval()
    batch = RenderBatch.from_dict(torch.utils.data.default_collate([data[0], data[1]]))
    inputs = batch.generator_inputs()
    with torch.no_grad():
        ref, _ = net(**inputs)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            low, _ = net(**inputs)
    err = (low.float() - ref).abs()
    # bfloat16 keeps 8 bits of mantissa: about 0.4% of a value per operation
    assert err.mean() < 5e-3 and err.max() < 5e-2, (err.mean(), err.max())


def test_bf16_training_follows_fp32(data, tmp_path):
    # the texels at quick's rate, 2e-4 x 100 (a faster network rate, so 20 steps show a curve)
    cfg = TINY.replace(steps=20, log_every=5, lr_g=2e-3, texture_lr_scale=10.0)
    ref = train_renderer(data, tmp_path / "fp32", cfg, progress=False)
    low = train_renderer(data, tmp_path / "bf16", cfg.replace(precision="bf16"), progress=False)
    assert low.skipped_steps == 0
    import csv

    def l1(res):
        with open(res.log_path, newline="") as f:
            return [float(r["l1"]) for r in csv.DictReader(f)]

    a, b = l1(ref), l1(low)
    assert len(a) == len(b) == 4
    # The same run in lower precision: its loss curve no more than 10% above the reference's
    # (what low precision would break is learning: texel updates lost to rounding), and within
    # 20% under it (the same curve, not another). The two runs part as they go: on a CPU whose
    # bfloat16 matmuls run on AMX units (Intel Xeon) the last logged L1 came out 12% under the
    # reference's (0.0364 against 0.0415), on an AMD EPYC within 10% either way.
    for x, y in zip(a, b, strict=True):
        assert 0.8 * x <= y <= 1.1 * x, (a, b)
    for k, v in low.net.state_dict().items():
        assert v.dtype == ref.net.state_dict()[k].dtype and torch.isfinite(v).all(), k
