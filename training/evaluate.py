"""Evaluation of trained renderers on unseen motions from unseen cameras (``dng eval``).

Every method (our renderer, the baselines, ablations) is an object with
``render(batch_dict) -> (B, 3, H, W)`` for frame t of a collated batch
(:func:`training.baselines.load_for_evaluation`). Each test sample holds frames t-1, t, t+1 of
one camera; a method renders frame t (with t-1 as its previous frame) and frame t+1 (with t),
so every sample gives two scored frames and one consecutive pair for the temporal metric.

Metrics (:mod:`training.metrics`): per-frame MSE (pixel values in [0, 1]), PSNR and SSIM, their
masked versions on the garment region (the union of the ground-truth garment mask and the proxy's
coverage, which does not depend on the method), and flicker. FID and the video-FID stand-in
(:mod:`training.inception`) need an InceptionV3 weights file, and tLP (:mod:`training.lpips`) an
LPIPS weights file; without one they are reported as unavailable.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from training.configs import PlainConfig
from training.metrics import FrameMetrics


@dataclass(frozen=True)
class EvalConfig(PlainConfig):
    """How the evaluation runs."""

    kind: ClassVar[str] = "eval"

    batch_size: int = 4
    """Samples rendered per call."""
    inception_path: str = ""
    """torchvision-layout InceptionV3 weights (``inception_v3_google-*.pth``) for FID and video
    FID; empty: both are reported as unavailable."""
    inception_width_scale: float = 1.0
    """Width of the InceptionV3 the weights belong to (1.0: torchvision's; smaller for tests)."""
    lpips_path: str = ""
    """``lpips`` AlexNet weights (:mod:`training.lpips`) for tLP; empty: reported unavailable."""
    lpips_width_scale: float = 1.0
    """Width of the AlexNet the LPIPS weights belong to (1.0: the real one; smaller for tests)."""
    sheet_samples: int = 4
    """Test samples shown per motion in the comparison picture."""


def next_frame_batch(batch: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The same batch moved one frame on: frame t+1 at index 1 with frame t as its previous.

    batch : collated samples, every value (B, 3, C, H, W) with frames t-1, t, t+1 on axis 1.
    Returns values (B, 3, C, H, W) holding frames t, t+1, t+1.
    """
    return {k: v[:, [1, 2, 2]] for k, v in batch.items()}


def garment_region(batch: Mapping[str, torch.Tensor], frame: int = 1) -> torch.Tensor:
    """(B, 1, H, W) float mask: ground-truth garment coverage or proxy coverage at ``frame``."""
    return torch.maximum(
        (batch["target_mask"][:, frame] > 0.5).float(), (batch["proxy_mask"][:, frame] > 0).float()
    )


def _batches(dataset, batch_size: int):
    for start in range(0, len(dataset), batch_size):
        idx = range(start, min(start + batch_size, len(dataset)))
        yield torch.utils.data.default_collate([dataset[i] for i in idx])


def _to_uint8(images: torch.Tensor) -> list[np.ndarray]:
    a = images.detach().float().clamp(0, 1).permute(0, 2, 3, 1).cpu().numpy()
    return list((a * 255 + 0.5).astype(np.uint8))


@dataclass
class MethodResult:
    """What one method scored on one test motion.

    metrics : FrameMetrics over frames t and t+1 of every sample (flicker per pair)
    frames_t : (N, 3, H, W) its renders of frame t; real_t the ground truth (for FID)
    pairs : N tensors (2, 3, H, W): its renders of t, t+1 (for video FID); real_pairs likewise
    tiles : uint8 renders of the first samples, for the comparison picture
    """

    metrics: FrameMetrics
    frames_t: list
    real_t: list
    pairs: list
    real_pairs: list
    tiles: list


def evaluate_motion(
    methods: Mapping[str, tuple[object, object]], config: EvalConfig
) -> tuple[dict[str, MethodResult], list[np.ndarray]]:
    """Render and score every method on its test data set of one motion.

    methods : name -> (model with ``render``, data set); methods sharing a data set object read
        each batch once.
    Returns the per-method results and the ground-truth tiles of the first samples.
    """
    results = {
        name: MethodResult(FrameMetrics(), [], [], [], [], []) for name in methods
    }  # fmt: skip
    gt_tiles: list[np.ndarray] = []
    by_data: dict[int, list[str]] = {}
    for name, (_, data) in methods.items():
        by_data.setdefault(id(data), []).append(name)
    for names in by_data.values():
        data = methods[names[0]][1]
        seen = 0
        for batch in _batches(data, config.batch_size):
            later = next_frame_batch(batch)
            real_t, real_n = batch["target"][:, 1], later["target"][:, 1]
            mask_t, mask_n = garment_region(batch), garment_region(later)
            first = gt_tiles if len(gt_tiles) < config.sheet_samples else None
            for name in names:
                model = methods[name][0]
                r = results[name]
                with torch.no_grad():
                    out_t = model.render(batch).float().clamp(0, 1)
                    out_n = model.render(later).float().clamp(0, 1)
                for i in range(len(out_t)):
                    clip = seen + i
                    r.metrics.update(
                        out_t[i : i + 1], real_t[i : i + 1], mask_t[i : i + 1], clip=clip
                    )
                    r.metrics.update(
                        out_n[i : i + 1], real_n[i : i + 1], mask_n[i : i + 1], clip=clip
                    )
                    r.pairs.append(torch.stack([out_t[i], out_n[i]]))
                    r.real_pairs.append(torch.stack([real_t[i], real_n[i]]))
                r.frames_t.append(out_t)
                r.real_t.append(real_t)
                room = config.sheet_samples - len(r.tiles)
                if room > 0:
                    r.tiles += _to_uint8(out_t[:room])
            if first is not None:
                gt_tiles += _to_uint8(real_t[: config.sheet_samples - len(gt_tiles)])
            seen += len(real_t)
    return results, gt_tiles


def weights_scores(result: MethodResult, config: EvalConfig) -> dict:
    """The metrics that need a network's weights file: FID of frame t, the video-FID stand-in
    and tLP over the consecutive pairs, or their "unavailable" records."""
    from training.inception import InceptionConfig, fid, video_fid
    from training.lpips import tlp

    cfg = InceptionConfig(width_scale=config.inception_width_scale)
    weights = config.inception_path or None
    return {
        "fid": fid(torch.cat(result.real_t), torch.cat(result.frames_t), weights, cfg).to_dict(),
        "video_fid": video_fid(result.real_pairs, result.pairs, weights, cfg).to_dict(),
        "tlp": tlp(
            result.real_pairs, result.pairs, config.lpips_path or None, config.lpips_width_scale
        ).to_dict(),
    }
