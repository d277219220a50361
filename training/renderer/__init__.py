"""The neural renderer: a learned multi-scale texture on the proxy + motion features -> a
rendering network -> the garment image composited over the body-only background.

- configuration: :class:`RendererConfig`, ``PRESETS`` (``cpu``, ``paper``, ``tiny``), :func:`preset`;
- data contract: :class:`RenderBatch`, :func:`synthetic_scene`, :class:`SyntheticDataset`;
- networks: :class:`RenderNet` (texture + generator), :class:`PatchDiscriminator`;
- training: :func:`train_renderer` (resumable, torchrun-aware), :func:`finetune_body`,
  :func:`finetune_background`, :func:`finetune_relight`, :func:`load_model`, :func:`save_model`;
- live rendering: :class:`NeuralRenderer`, :class:`FrameState`.
"""

from training.renderer.config import PRESETS, RendererConfig, preset
from training.renderer.data import RenderBatch, SyntheticDataset, synthetic_scene
from training.renderer.inference import CropBox, FrameState, NeuralRenderer
from training.renderer.model import (
    PatchDiscriminator,
    RenderNet,
    background_finetune_parameters,
    relight_parameters,
)
from training.renderer.train import (
    RendererTrainResult,
    finetune_background,
    finetune_body,
    finetune_relight,
    load_model,
    save_model,
    train_renderer,
)

__all__ = [
    "PRESETS",
    "CropBox",
    "FrameState",
    "NeuralRenderer",
    "PatchDiscriminator",
    "RenderBatch",
    "RenderNet",
    "RendererConfig",
    "RendererTrainResult",
    "SyntheticDataset",
    "background_finetune_parameters",
    "finetune_background",
    "finetune_body",
    "finetune_relight",
    "load_model",
    "preset",
    "relight_parameters",
    "save_model",
    "synthetic_scene",
    "train_renderer",
]
