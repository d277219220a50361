"""What the baselines share: the config fields, the sample check, the U-Net and the uniform
``render(batch_dict)`` call (also offered for our renderer through :class:`RendererAdapter`).

A baseline sample is a renderer sample (:mod:`training.renderer.data`) plus ``proxy_shading``:

=============  =================  =====================================================
key            shape              meaning
=============  =================  =====================================================
proxy_shading  (3, 1, H, W)       Lambert shading of the proxy (camera-fixed light) in
                                  [0, 1], 0 off the proxy; frames t-1, t, t+1
=============  =================  =====================================================

Each model checks only the keys it reads (:func:`check_batch`), so the same data set trains
every baseline and our renderer.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import ClassVar

import torch
from torch import nn

from core.errors import InputError
from training.configs import PlainConfig
from training.renderer.data import CUR, RenderBatch
from training.schedule import check_decay_from, check_positive

#: Channels of every sample key (None: any count, e.g. the motion features).
CHANNELS: dict[str, int | None] = {
    "uv": 2,
    "motion": None,
    "proxy_mask": 1,
    "target": 3,
    "background": 3,
    "target_mask": 1,
    "proxy_shading": 1,
}
GAN_MODES = ("hinge", "lsgan")


def check_batch(
    batch: dict, keys: Iterable[str], name: str | None = None
) -> dict[str, torch.Tensor]:
    """Check the ``keys`` of a sample (no B) or a batch (leading B).

    Parameters
    ----------
    batch : dict of tensors (3, C, H, W) or (B, 3, C, H, W) (frames t-1, t, t+1)
    keys : the keys the caller reads
    name : file or data set named in the error

    Returns
    -------
    dict key -> (B, 3, C, H, W) float32 tensor; ``InputError`` on a missing key, a wrong shape
    or sizes that disagree
    """
    if not isinstance(batch, dict):
        raise InputError(f"a baseline sample must be a dict, got {type(batch).__name__}", name)
    keys = list(keys)
    missing = [k for k in keys if k not in batch]
    if missing:
        raise InputError(f"baseline sample is missing {missing}", name)
    out, ref = {}, None
    for k in keys:
        t = torch.as_tensor(batch[k])
        if t.dim() == 4:
            t = t.unsqueeze(0)
        c = CHANNELS.get(k)
        if t.dim() != 5 or t.shape[1] != 3 or (c is not None and t.shape[2] != c):
            want = f"(B, 3, {c or 'C'}, H, W) or (3, {c or 'C'}, H, W)"
            raise InputError(f"sample[{k!r}] must be {want}, got {tuple(t.shape)}", name)
        if ref is None:
            ref = (t.shape[0], *t.shape[3:])
        elif (t.shape[0], *t.shape[3:]) != ref:
            raise InputError(
                f"sample[{k!r}] has batch/size {(t.shape[0], *t.shape[3:])}, expected {ref}", name
            )
        out[k] = t.float()
    return out


@dataclass(frozen=True)
class BaselineConfig(PlainConfig):
    """Fields every baseline has (network size, GAN, optimiser, schedule). Subclassed per
    baseline; not used directly."""

    kind: ClassVar[str] = "baseline"

    image_size: int = 128
    """Training image size (square); any size divisible by ``2 ** n_down`` renders."""
    base_width: int = 16
    """Channels of the U-Net's first layer; doubled per level up to ``max_width``."""
    max_width: int = 128
    """Widest U-Net layer."""
    n_down: int = 5
    """U-Net levels (stride-2 convolutions); the bottleneck is ``image_size / 2 ** n_down``."""
    disc_width: int = 16
    """Channels of the PatchGAN's first layer (64 in pix2pix and the paper)."""
    gan_mode: str = "lsgan"
    """GAN loss: ``lsgan`` or ``hinge``."""
    w_l1: float = 10.0
    """Weight of the L1 loss to the ground truth at frame t."""
    w_pyramid: float = 0.0
    """Weight of the Laplacian-pyramid L1 (as the renderer's; 0: the baselines' own losses)."""
    w_detail: float = 0.0
    """Weight of the local detail-energy L1 (as the renderer's; 0: off)."""
    w_gradient: float = 0.0
    """Weight of the multi-scale gradient-similarity loss (as the renderer's; 0: off)."""
    w_gan: float = 0.0
    """Weight of the generator's GAN loss (0 and no discriminator for L1-only baselines)."""
    w_fm: float = 0.0
    """Weight of discriminator feature matching."""
    w_perceptual: float = 0.0
    """Weight of the VGG perceptual loss (needs ``vgg_path``)."""
    vgg_path: str = ""
    """torchvision-layout VGG19 weights for the perceptual loss; empty: the loss is off."""
    vgg_channels: tuple[int, ...] = ()
    """VGG conv widths (0 = max pool) when not VGG19's (tests)."""
    lr_g: float = 2e-4
    """Adam learning rate of the generator (and neural texture)."""
    lr_d: float = 2e-4
    """Adam learning rate of the discriminator."""
    lr_decay_from: float = 1.0
    """Fraction of the steps after which both learning rates fall linearly to zero (as the
    renderer's ``lr_decay_from``); 1.0 keeps them constant. A project's baselines train on our
    renderer's schedule, its ``lr_g`` and this (``pipeline.config.baseline_config``, where the
    validation figures that chose it are)."""
    betas: tuple[float, float] = (0.5, 0.999)
    """Adam betas."""
    texture_lr_scale: float = 1.0
    """Factor on ``lr_g`` for a neural texture's texels (DNR; Pix2Pix has none): 1, DNR's one
    rate, by default; in a project the renderer's (``RendererConfig.texture_lr_scale``, where
    the validation figures that chose it are, DNR's included)."""
    adam_eps: float = 1e-15
    """Adam's ``eps``: the renderer's (``training.renderer.config.RendererConfig.adam_eps``,
    where the validation figures that chose it are). Model files written before this field
    existed read as 1e-8."""
    batch_size: int = 2
    """Samples per step."""
    steps: int = 1000
    """Optimisation steps of a run."""
    seed: int = 0
    """Seeds weights, dropout and sample order."""
    checkpoint_every: int = 100
    """Steps between resumable checkpoints."""
    log_every: int = 10
    """Steps between CSV log rows (means since the last row)."""

    def __post_init__(self) -> None:
        for name in (
            "image_size", "base_width", "max_width", "n_down", "disc_width", "batch_size",
            "checkpoint_every", "log_every",
        ):  # fmt: skip
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, int) and v > 0):
                raise InputError(f"{self.kind} config {name}={v!r} must be a positive integer")
        for name in ("steps", "seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, int) and v >= 0):
                raise InputError(f"{self.kind} config {name}={v!r} must be an integer >= 0")
        if self.image_size % 2**self.n_down:
            raise InputError(
                f"{self.kind} config image_size {self.image_size} must be divisible by "
                f"2 ** n_down = {2**self.n_down}"
            )
        if self.gan_mode not in GAN_MODES:
            raise InputError(f"gan_mode must be one of {GAN_MODES}, got {self.gan_mode!r}")
        for name in (
            "w_l1",
            "w_pyramid",
            "w_detail",
            "w_gradient",
            "w_gan",
            "w_fm",
            "w_perceptual",
            "lr_g",
            "lr_d",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"{self.kind} config {name}={v!r} must be a finite number >= 0")
        if any(not isinstance(c, int) or c < 0 for c in self.vgg_channels):
            raise InputError(f"vgg_channels={self.vgg_channels!r} must be integers >= 0")
        check_decay_from(self.lr_decay_from, self.kind)
        check_positive(self.adam_eps, self.kind, "adam_eps")
        check_positive(self.texture_lr_scale, self.kind, "texture_lr_scale")

    @property
    def baseline(self) -> str:
        """The entry of ``KINDS`` this config trains."""
        raise NotImplementedError

    def replace(self, **changes):
        """A copy with some fields changed (validated)."""
        return replace(self, **changes)


class UNet(nn.Module):
    """pix2pix's U-Net: stride-2 4x4 convs down, transposed convs up, skips concatenated.

    Parameters
    ----------
    in_channels, out_channels : image channels in and out
    base, max_width : first-level width, doubled per level up to ``max_width``
    n_down : levels; input sides must be divisible by ``2 ** n_down``
    dropout : dropout of the three innermost up-levels, in training mode only (pix2pix: 0.5)

    ``forward``: (B, in_channels, H, W) -> (B, out_channels, H, W) in (0, 1) (sigmoid).
    Instance norm everywhere except the outermost and innermost levels.
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        base: int,
        max_width: int,
        n_down: int,
        dropout: float = 0.0,
    ):
        super().__init__()
        widths = [min(base * 2**i, max_width) for i in range(n_down)]
        self.n_down = n_down
        self.downs = nn.ModuleList()
        c = in_channels
        for i, w in enumerate(widths):
            layers: list[nn.Module] = [nn.Conv2d(c, w, 4, 2, 1)]
            if 0 < i < n_down - 1:
                layers.append(nn.InstanceNorm2d(w, affine=True))
            layers.append(nn.LeakyReLU(0.2))
            self.downs.append(nn.Sequential(*layers))
            c = w
        self.ups = nn.ModuleList()
        for j, level in enumerate(reversed(range(n_down))):
            cin = widths[level] * (1 if level == n_down - 1 else 2)
            if level == 0:
                self.ups.append(nn.ConvTranspose2d(cin, out_channels, 4, 2, 1))
                continue
            cout = widths[level - 1]
            layers = [
                nn.ConvTranspose2d(cin, cout, 4, 2, 1),
                nn.InstanceNorm2d(cout, affine=True),
                nn.ReLU(),
            ]
            if dropout > 0 and j < 3:
                layers.append(nn.Dropout(dropout))
            self.ups.append(nn.Sequential(*layers))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        h = x
        for down in self.downs:
            h = down(h)
            skips.append(h)
        h = skips.pop()
        for up in self.ups:
            h = up(h)
            if skips:
                h = torch.cat([h, skips.pop()], 1)
        return torch.sigmoid(h)


class BaselineModel(nn.Module):
    """The interface the training loop and the evaluation use (subclassed per baseline).

    Subclasses set ``kind``, ``config`` and ``required_keys`` and implement ``forward``,
    ``make_discriminator`` and ``disc_inputs``.
    """

    kind: str = ""
    required_keys: tuple[str, ...] = ()
    #: Weight of :meth:`extra_loss` in the generator loss (its own regulariser).
    extra_weight: float = 0.0

    def forward(self, batch: dict) -> tuple[torch.Tensor, dict]:
        """Checked batch (key -> (B, 3, C, H, W)) -> (RGB at frame t (B, 3, H, W), aux dict)."""
        raise NotImplementedError

    def make_discriminator(self) -> nn.Module | None:
        """A fresh discriminator for training, or None (L1-only)."""
        return None

    def disc_inputs(
        self, batch: dict, fake: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:  # pragma: no cover - abstract
        """(real, fake) inputs of the discriminator, each (B', C, H, W)."""
        raise NotImplementedError

    def extra_loss(self, batch: dict, aux: dict) -> torch.Tensor:
        """The model's own regulariser (unweighted scalar); zero by default."""
        return batch["target"].new_zeros(())

    # The model is its own :class:`training.adversarial.Method`:

    def generate(self, net: nn.Module, batch: dict) -> tuple[torch.Tensor, dict]:
        """``net`` (this model, or its DistributedDataParallel wrapper) on a checked batch."""
        return net(batch)

    def target(self, batch: dict) -> torch.Tensor:
        """The ground truth at frame t, (B, 3, H, W)."""
        return batch["target"][:, CUR]

    def check(self, batch: dict, keys: Iterable[str] = ()) -> dict[str, torch.Tensor]:
        """:func:`check_batch` on ``required_keys`` (+ ``keys``), moved to the model's device,
        with a size divisible by the U-Net's stride."""
        out = check_batch(batch, dict.fromkeys((*self.required_keys, *keys)))
        stride = 2**self.config.n_down
        h, w = next(iter(out.values())).shape[-2:]
        if h % stride or w % stride:
            raise InputError(f"{self.kind}: image size {h} x {w} must be divisible by {stride}")
        device = next(self.parameters()).device
        return {k: v.to(device) for k, v in out.items()}

    def render(self, batch: dict) -> torch.Tensor:
        """Frame t of a collated batch (or one sample): (B, 3, H, W) float32 in [0, 1].

        Runs in eval mode without gradients (the mode is restored afterwards).
        """
        checked = self.check(batch)
        was = self.training
        self.eval()
        try:
            with torch.no_grad():
                rgb, _ = self(checked)
        finally:
            self.train(was)
        return rgb


class RendererAdapter:
    """Our renderer behind the baselines' call: ``render(batch_dict) -> (B, 3, H, W)``.

    net : training.renderer.model.RenderNet (eval mode is used for the call)
    """

    kind = "ours"

    def __init__(self, net):
        self.net = net

    def render(self, batch: dict) -> torch.Tensor:
        cfg = self.net.config
        b = RenderBatch.from_dict(
            {k: batch[k] for k in RenderBatch.__dataclass_fields__ if k in batch},
            cfg.motion_channels,
        )
        b = b.to(next(self.net.parameters()).device)
        was = self.net.training
        self.net.eval()
        try:
            with torch.no_grad():
                rgb, _ = self.net(**b.generator_inputs(cfg.use_motion))
        finally:
            self.net.train(was)
        return rgb


__all__ = [
    "CHANNELS",
    "CUR",
    "BaselineConfig",
    "BaselineModel",
    "RendererAdapter",
    "UNet",
    "check_batch",
]
