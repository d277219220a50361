"""Baselines of the paper's comparison table, trained on the same samples as our renderer.

- ``pix2pix`` (Isola et al. 2017): U-Net from the shaded proxy render + conditional PatchGAN,
  L1 x 100 (:mod:`training.baselines.pix2pix`);
- ``dnr`` (Thies et al. 2019): neural texture at the proxy UVs + U-Net, L1 only;
  ``dnr-gan``: the same network with our loss and temporal PatchGAN
  (:mod:`training.baselines.dnr`);
- one training loop for all: :func:`train_baseline` (resumable), :func:`load_baseline`;
- one inference call for all, our renderer included: ``model.render(batch_dict) -> (B, 3, H, W)``
  (frame t of a collated batch; :func:`load_for_evaluation` loads any of the model files).
"""

from training.baselines.common import (
    BaselineConfig,
    BaselineModel,
    RendererAdapter,
    UNet,
    check_batch,
)
from training.baselines.dnr import DNR_GAN_PRESETS, DNR_PRESETS, DeferredNeuralRenderer, DNRConfig
from training.baselines.pix2pix import PIX2PIX_PRESETS, Pix2Pix, Pix2PixConfig, shaded_input
from training.baselines.train import (
    KINDS,
    PRESETS,
    BaselineTrainResult,
    build_model,
    load_baseline,
    load_for_evaluation,
    preset,
    save_baseline,
    synthetic_batch,
    train_baseline,
)

__all__ = [
    "DNR_GAN_PRESETS",
    "DNR_PRESETS",
    "KINDS",
    "PIX2PIX_PRESETS",
    "PRESETS",
    "BaselineConfig",
    "BaselineModel",
    "BaselineTrainResult",
    "DNRConfig",
    "DeferredNeuralRenderer",
    "Pix2Pix",
    "Pix2PixConfig",
    "RendererAdapter",
    "UNet",
    "build_model",
    "check_batch",
    "load_baseline",
    "load_for_evaluation",
    "preset",
    "save_baseline",
    "shaded_input",
    "synthetic_batch",
    "train_baseline",
]
