"""Pix2Pix baseline (Isola et al. 2017): a U-Net from the shaded proxy render to the final image,
trained with L1 (weight 100) and a conditional 70 px PatchGAN.

Input at frame t: ``background * (1 - proxy_mask) + proxy_shading * proxy_mask`` (the proxy,
Lambert-shaded with a camera-fixed light, pasted over the body-only background: 3 channels),
followed by the proxy mask (1 channel) when ``use_mask``. Output: RGB at frame t in [0, 1].
The discriminator sees ``[input, image]`` (real: the ground truth; fake: the rendering), so it
judges the image given its condition. Dropout (0.5 on the three innermost up-levels) is the
generator's noise in training, as in pix2pix; rendering is deterministic (eval mode, no dropout).
The PatchGAN is the project's spectral-norm one (:class:`PatchDiscriminator`) and the GAN loss
LSGAN (pix2pix's code offers it; the paper used the log loss).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import nn

from core.errors import InputError
from training.baselines.common import BaselineConfig, BaselineModel, UNet
from training.renderer.data import CUR
from training.renderer.model import PatchDiscriminator


@dataclass(frozen=True)
class Pix2PixConfig(BaselineConfig):
    """Pix2Pix: U-Net generator, conditional PatchGAN, L1 x 100 + GAN.

    ``PIX2PIX_PRESETS["cpu"]`` (the defaults): one training step at 128 px, batch 2, costs
    0.11 s of CPU on one thread (median; 0.22 s wall on the shared 2-core development machine
    at load 7), measured with ``.venv/bin/python -m training.baselines --bench pix2pix``.
    """

    kind: ClassVar[str] = "pix2pix"

    w_l1: float = 100.0
    """Weight of L1 (pix2pix's lambda = 100)."""
    w_gan: float = 1.0
    """Weight of the generator's GAN loss."""
    use_mask: bool = True
    """Concatenate the proxy mask to the shaded input (4 input channels instead of 3)."""
    dropout: float = 0.5
    """Dropout of the three innermost U-Net up-levels while training."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0.0 <= self.dropout < 1.0:
            raise InputError(f"pix2pix config dropout={self.dropout!r} must be in [0, 1)")

    @property
    def baseline(self) -> str:
        return "pix2pix"


#: ``cpu``: minutes on one core at 128 px; ``paper``: pix2pix's widths (64 .. 512, 64-channel
#: PatchGAN) at 512 px; ``tiny``: tests.
PIX2PIX_PRESETS: dict[str, Pix2PixConfig] = {
    "cpu": Pix2PixConfig(),
    "paper": Pix2PixConfig(
        image_size=512,
        base_width=64,
        max_width=512,
        n_down=8,
        disc_width=64,
        steps=100000,
        checkpoint_every=1000,
        log_every=50,
    ),
    "tiny": Pix2PixConfig(
        image_size=32,
        base_width=8,
        max_width=16,
        n_down=3,
        disc_width=8,
        steps=20,
        checkpoint_every=5,
        log_every=2,
        lr_g=1e-3,
    ),
}


def shaded_input(batch: dict, frame: int = CUR, use_mask: bool = True) -> torch.Tensor:
    """The generator's input at ``frame``.

    batch : checked dict with ``background`` (B, 3, 3, H, W), ``proxy_shading`` and
    ``proxy_mask`` (B, 3, 1, H, W) -> (B, 3 [+1], H, W) float32 in [0, 1].
    """
    m = batch["proxy_mask"][:, frame]
    shading = batch["proxy_shading"][:, frame].expand(-1, 3, -1, -1)
    x = batch["background"][:, frame] * (1 - m) + shading * m
    return torch.cat([x, m], 1) if use_mask else x


class Pix2Pix(BaselineModel):
    """The Pix2Pix generator (``render`` / ``forward``) and its discriminator factory."""

    kind = "pix2pix"
    required_keys = ("proxy_shading", "proxy_mask", "background")

    def __init__(self, config: Pix2PixConfig):
        super().__init__()
        self.config = config
        self.in_channels = 4 if config.use_mask else 3
        self.generator = UNet(
            self.in_channels,
            3,
            config.base_width,
            config.max_width,
            config.n_down,
            config.dropout,
        )

    def forward(self, batch: dict) -> tuple[torch.Tensor, dict]:
        """Checked batch -> (RGB (B, 3, H, W) at frame t, {"input": (B, Cin, H, W)})."""
        x = shaded_input(batch, CUR, self.config.use_mask)
        return self.generator(x), {"input": x}

    def make_discriminator(self) -> nn.Module:
        return PatchDiscriminator(self.config.disc_width, in_channels=self.in_channels + 3)

    def disc_inputs(self, batch: dict, fake: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Conditional pairs: real ``[input, I_t]``, fake ``[input, R_t]``: (B, Cin + 3, H, W)."""
        x = shaded_input(batch, CUR, self.config.use_mask)
        return torch.cat([x, batch["target"][:, CUR]], 1), torch.cat([x, fake], 1)
