"""Deferred Neural Rendering baseline (Thies et al. 2019): a neural texture sampled at the proxy's
UVs and a U-Net that renders it, frame by frame (no motion features, no temporal input).

**Compositing.** The U-Net's input is ``[texture sample (L * C channels, 0 off the proxy),
background * 2 - 1 (3), proxy mask (1)]`` and its output is the whole RGB frame: the network
sees the body-only background everywhere and learns to copy it through its skip connections
where there is no garment, and to paint the garment (also beyond the proxy's silhouette, where
the detailed garment is larger) over it. There is no explicit alpha blend, as in DNR, whose
renderer outputs the final image.

**Variants.**

- ``dnr``: L1 only (DNR's loss), plus DNR's texture regulariser: the first 3 channels of the
  sampled texture are pulled towards the ground truth on the proxy (weight ``w_texture``), so
  the texture's first level starts as a colour texture.
- ``dnr-gan``: our loss on the same network: ``10 (L1 + perceptual) + 5 FM + 0.5 GAN`` with the
  temporal PatchGAN on consecutive-frame pairs (``[R_t, I_{t-1}]``, ``[I_{t+1}, R_t]`` fake;
  the ground-truth pairs real), as :mod:`training.renderer.train` trains our renderer. The
  perceptual loss is on only with a VGG19 weights file (``vgg_path``). In a project the
  weights are the ones our renderer trains with, overrides included
  (:func:`pipeline.config.baseline_config`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import nn

from core.errors import InputError
from training.baselines.common import BaselineConfig, BaselineModel, UNet
from training.renderer.data import CUR, NEXT, PREV
from training.renderer.model import NeuralTexture, PatchDiscriminator, texture_colour_loss


@dataclass(frozen=True)
class DNRConfig(BaselineConfig):
    """Deferred neural rendering: neural texture + U-Net; ``gan`` picks ``dnr-gan``.

    ``DNR_PRESETS["cpu"]`` (the defaults): one training step at 128 px, batch 2, costs 0.125 s
    (``dnr``) and 0.169 s (``dnr-gan``, perceptual loss off) of CPU on one thread (medians, 16
    texture channels; 0.11 and 0.20 s with the 8 it had, on a busier machine), measured with
    ``.venv/bin/python -m training.baselines --bench dnr dnr-gan``. A VGG19 perceptual loss
    adds its own cost.
    """

    kind: ClassVar[str] = "dnr"

    texture_sizes: tuple[int, ...] = (256, 128, 64, 32)
    """Texels per side of each neural-texture level. The cpu preset halves our renderer's
    (512, 256, 128, 64): the texture's sampling backward dominates a CPU step (0.3 s at 512 x
    16 channels); the ``paper`` preset has the full size."""
    texture_channels: int = 16
    """Channels per texture level: 16, as DNR's paper and our renderer (it was 8 here, half our
    renderer's texture capacity)."""
    w_texture: float = 1.0
    """Weight of DNR's regulariser (first 3 texture channels ~ the image on the proxy); 0: off."""
    gan: bool = False
    """Train with our loss and the temporal PatchGAN (the ``dnr-gan`` variant)."""
    lr_g: float = 1e-4
    """Adam learning rate of the U-Net and the texture: the paper's rate for its renderer. A
    project's baselines train at our renderer's rate and schedule instead
    (``pipeline.config.baseline_config``; the report's "What each method got" lists them)."""
    lr_d: float = 3e-4
    """Adam learning rate of the discriminator (the paper's, as our renderer's)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.texture_channels, int) or self.texture_channels < 3:
            raise InputError(f"dnr texture_channels={self.texture_channels!r} must be >= 3")
        if not self.texture_sizes or any(
            not isinstance(s, int) or s < 2 for s in self.texture_sizes
        ):
            raise InputError(f"dnr texture_sizes={self.texture_sizes!r} must be integers >= 2")
        if self.w_texture < 0:
            raise InputError(f"dnr w_texture={self.w_texture!r} must be >= 0")
        if not self.gan and (self.w_gan or self.w_fm or self.w_perceptual):
            raise InputError("dnr (gan=False) trains with L1 only: set gan=True for dnr-gan")

    @property
    def baseline(self) -> str:
        return "dnr-gan" if self.gan else "dnr"


_TINY = {
    "image_size": 32,
    "texture_sizes": (32, 16),
    "texture_channels": 4,
    "base_width": 8,
    "max_width": 16,
    "n_down": 3,
    "disc_width": 8,
    "steps": 20,
    "checkpoint_every": 5,
    "log_every": 2,
    "lr_g": 2e-3,
}
_PAPER = {
    "image_size": 512,
    "texture_sizes": (512, 256, 128, 64),
    "texture_channels": 16,
    "base_width": 64,
    "max_width": 512,
    "n_down": 8,
    "disc_width": 64,
    "steps": 100000,
    "checkpoint_every": 1000,
    "log_every": 50,
}
_GAN = {"gan": True, "w_l1": 10.0, "w_perceptual": 10.0, "w_fm": 5.0, "w_gan": 0.5}

#: ``cpu``: minutes on one core at 128 px; ``paper``: 512 px, DNR's texture (512 px x 16
#: channels x 4 levels) and pix2pix's U-Net widths; ``tiny``: tests.
DNR_PRESETS: dict[str, DNRConfig] = {
    "cpu": DNRConfig(),
    "paper": DNRConfig(**_PAPER),
    "tiny": DNRConfig(**_TINY),
}
DNR_GAN_PRESETS: dict[str, DNRConfig] = {
    "cpu": DNRConfig(**_GAN),
    "paper": DNRConfig(**_PAPER, **_GAN),
    "tiny": DNRConfig(**_TINY, **_GAN),
}


class DeferredNeuralRenderer(BaselineModel):
    """Neural texture + U-Net renderer (``render`` / ``forward``) and, for ``dnr-gan``, the
    temporal discriminator factory."""

    required_keys = ("uv", "proxy_mask", "background")

    def __init__(self, config: DNRConfig):
        super().__init__()
        self.config = config
        self.kind = config.baseline
        self.extra_weight = config.w_texture
        self.texture = NeuralTexture(config.texture_sizes, config.texture_channels, config.seed)
        self.generator = UNet(
            self.texture.out_channels + 4, 3, config.base_width, config.max_width, config.n_down
        )

    def forward(self, batch: dict) -> tuple[torch.Tensor, dict]:
        """Checked batch -> (RGB (B, 3, H, W) at frame t, {"texture": (B, L * C, H, W)})."""
        m = batch["proxy_mask"][:, CUR]
        tex = self.texture(batch["uv"][:, CUR], m)
        x = torch.cat([tex, batch["background"][:, CUR] * 2 - 1, m], 1)
        return self.generator(x), {"texture": tex}

    def extra_loss(self, batch: dict, aux: dict) -> torch.Tensor:
        """DNR's texture regulariser: L1 of the first 3 sampled channels to the image, on the
        proxy (mean over the proxy's pixels and channels)."""
        return texture_colour_loss(
            aux["texture"], batch["target"][:, CUR], batch["proxy_mask"][:, CUR]
        )

    def make_discriminator(self) -> nn.Module | None:
        return PatchDiscriminator(self.config.disc_width) if self.config.gan else None

    def disc_inputs(self, batch: dict, fake: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Temporal pairs (2B, 6, H, W): real ``[I_t, I_{t-1}]``, ``[I_{t+1}, I_t]``; fake
        ``[R_t, I_{t-1}]``, ``[I_{t+1}, R_t]``."""
        t = batch["target"]
        prev, cur, nxt = t[:, PREV], t[:, CUR], t[:, NEXT]
        real = torch.cat([torch.cat([cur, prev], 1), torch.cat([nxt, cur], 1)])
        fake_pairs = torch.cat([torch.cat([fake, prev], 1), torch.cat([nxt, fake], 1)])
        return real, fake_pairs
