"""The neural renderer's configuration and named presets."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import ClassVar

from core.errors import InputError
from training.configs import PlainConfig
from training.schedule import check_decay_from, check_positive

#: Channels of the paper's motion features: 19 joints x 5 frames (core.features layout).
MOTION_CHANNELS = 95
GAN_MODES = ("hinge", "lsgan")
PRECISIONS = ("auto", "fp32", "bf16", "fp16")


@dataclass(frozen=True)
class RendererConfig(PlainConfig):
    """Neural texture, rendering network, discriminator, losses and training schedule.

    The defaults are the ``cpu`` preset (small widths, 128 px); ``PRESETS["paper"]`` has the
    published sizes (DESIGN, "The method").
    """

    kind: ClassVar[str] = "renderer"

    image_size: int = 128
    """Training image size in pixels (square); the network works on any size divisible by
    ``2 ** n_down`` at inference."""
    texture_sizes: tuple[int, ...] = (256, 128, 64, 32)
    """Texels per side of each neural-texture level (sampled bilinearly, concatenated). The
    paper's (512, 256, 128, 64) has more texels than a 128 px image has garment pixels, and its
    sampling backward dominates a CPU step; the ``paper`` preset has it."""
    texture_channels: int = 16
    """Channels per texture level (4 levels x 16 = 64 channels in the paper)."""
    motion_channels: int = MOTION_CHANNELS
    """Channels of the motion-feature map (19 joints x 5 frames)."""
    use_motion: bool = True
    """Feed the motion features to the network (False: the "without motion features" ablation,
    whose input is the texture sample and the proxy's coverage mask, as DNR's; without the mask
    it never found the garment: docs/decisions.md, "use_motion")."""
    use_temporal: bool = True
    """Condition the SPADE block on frame t-1's latent and show the discriminator pairs of
    consecutive frames (False: the "no temporal conditioning" ablation). Worth nothing on L1
    alone with an embedded target (docs/decisions.md, "use_temporal")."""
    base_width: int = 16
    """Channels of the encoder's first layer; each downsampling doubles it up to ``max_width``.
    The speed knob."""
    max_width: int = 128
    """Channels of the latent code (512 in the paper: 16 x 16 x 512 at 512 px)."""
    n_down: int = 3
    """Stride-2 encoder stages: the latent is ``image_size / 2 ** n_down`` per side."""
    skip_connections: bool = True
    """U-Net skips from the encoder (frame t) to the decoder at every scale. Not in the paper
    (its decoder starts from the 16 x 16 latent alone); with a few thousand CPU steps they give
    the folds their sharpness. The ``paper`` preset turns them off."""
    texture_readout: bool = True
    """A 1 x 1 conv from frame t's texture sample straight to the RGB logits, beside the
    refinement's (192 weights). Without it the frill tiers reached the image only through the
    encoder, decoder and refinement, too slowly for a few hundred steps: the garment's detail on
    validation was 0.49 of the ground truth's (docs/decisions.md, "texture_readout"). Not in the
    paper; off in the ``paper`` preset."""
    background_guide: bool = False
    """Show the decoder the body-only background image, averaged down to each of its scales
    (3 more input channels to each up stage's fuse): the encoder's input is zero off the proxy
    and never shows the body, so the body in front of the garment or between its tiers could
    only be guessed. Not in the paper (whose decoder sees the background only in the blend)."""
    alpha_prior: float = 12.0
    """With ``texture_readout`` and ``blend_output``: a logit added to the blend's alpha on the
    proxy's coverage, so the garment starts opaque where the proxy is and the network learns
    where to carve (tier gaps) from there. Learned from nothing, the alpha let the backdrop
    through the garment; 3, 6 and 12 lowered garment-region MSE on validation step by step
    (docs/decisions.md, "alpha_prior"). Not in the paper; 0 in the ``paper`` preset; older
    model files read as 0."""
    blend_output: bool = True
    """Blend the final RGB with the background image by a predicted alpha, so the body off the
    garment is exact instead of a learned copy. Not in the paper; off in the ``paper`` preset."""
    decoder_features: int = 16
    """Channels of the garment features U, of the background features and of the refinement
    blocks."""
    background_width: int = 16
    """Hidden channels of the small conv net that turns the background image into features."""
    disc_width: int = 16
    """Channels of the discriminator's first layer (64 in the paper's PatchGAN)."""
    gan_mode: str = "hinge"
    """GAN loss: ``hinge`` (default) or ``lsgan``."""
    vgg_path: str = ""
    """torchvision-layout VGG19 ``.pth`` (``features.N.weight`` keys) for the perceptual loss;
    empty turns the perceptual loss off (the log says so)."""
    vgg_channels: tuple[int, ...] = ()
    """Conv widths of the VGG (0 = max pool) when not VGG19's; empty means VGG19. For tests."""
    w_l1: float = 10.0
    """Weight of L1 (the paper: 10 x (L1 + perceptual))."""
    w_pyramid: float = 20.0
    """Weight of the Laplacian-pyramid L1 (:func:`training.losses.pyramid_l1`): every band of
    detail counted as much as the colours. With ``w_detail`` it stands in for the paper's
    perceptual loss (no weights here); chosen on the validation motion (docs/decisions.md,
    "texture_readout"). Not in the paper; 0 in the ``paper`` preset."""
    w_detail: float = 5.0
    """Weight of the local detail-energy L1 (:func:`training.losses.detail_energy_l1`): as much
    fine detail as the ground truth in each 8 px window, wherever in it. The per-pixel losses
    alone drew a blur where a tier's edge is uncertain (detail 0.61 of the ground truth's on
    validation, 0.83 with this). At 10 it drew detail even where a rim's place is uncertain:
    5 lowered MSE and GMSD on validation in two seeds (docs/decisions.md, "w_detail"). Not in
    the paper; 0 in the ``paper`` preset."""
    w_gradient: float = 0.0
    """Weight of the multi-scale gradient-magnitude similarity
    (:func:`training.losses.gradient_similarity_loss`): each edge of the ground truth, faint or
    strong, in its place. At 2 it changed nothing on validation; at 10 it bought GMSD under the
    seed spread and cost MSE and SSIM (docs/decisions.md, "w_detail"). Not in the paper; 0 in
    the ``paper`` preset."""
    w_perceptual: float = 10.0
    """Weight of the perceptual loss."""
    w_fm: float = 5.0
    """Weight of discriminator feature matching."""
    w_gan: float = 0.5
    """Weight of the generator's GAN loss."""
    w_texture: float = 0.0
    """Weight of DNR's texture regulariser on our neural texture
    (:func:`~training.renderer.model.texture_colour_loss`); 0, the paper's renderer has none, and
    1 gained nothing beyond seed noise (docs/decisions.md, "w_texture")."""
    lr_g: float = 2e-4
    """Adam learning rate of the network and the neural texture (1e-4 in the paper and its
    preset; 2e-4 for the few thousand steps a CPU run can afford, as the baselines)."""
    lr_d: float = 3e-4
    """Adam learning rate of the discriminator."""
    lr_decay_from: float = 0.5
    """Fraction of a run's steps after which both learning rates fall linearly to zero at the
    end (``training.schedule``); 1.0 keeps them constant, as the paper and its preset. 0.5 was
    as good or better on validation (docs/decisions.md, "lr_decay_from")."""
    betas: tuple[float, float] = (0.5, 0.999)
    """Adam betas of both optimisers."""
    texture_lr_scale: float = 100.0
    """Factor on ``lr_g`` (and its schedule) for the neural texture's texels (1: the network's
    rate, the paper's). Adam moves a texel about the rate a step, so at 1 the textures stayed
    noise (docs/decisions.md, "texture_lr_scale"). Older model files read as 1."""
    adam_eps: float = 1e-15
    """Adam's ``eps`` (both optimisers; every method has the same): a neural texel's gradient is
    about 1e-10, where torch's 1e-8 let Adam take a hundredth of a step (docs/decisions.md,
    "adam_eps"). Older model files read as 1e-8."""
    batch_size: int = 2
    """Samples per step (per process under torchrun)."""
    steps: int = 1000
    """Optimisation steps of a from-scratch run (cpu preset: about 15 minutes on one core)."""
    body_finetune_fraction: float = 0.25
    """Fine-tuning to a new body shape runs this fraction of ``steps`` by default."""
    background_finetune_steps: int = 200
    """Default steps of fine-tuning to a new background / lighting."""
    crop_margin: int = 16
    """Pixels added around the proxy's screen box before the crop is snapped to the stride."""
    seed: int = 0
    """Seeds initial weights and sample order: the same seed gives the same weights."""
    checkpoint_every: int = 100
    """Steps between resumable checkpoints."""
    log_every: int = 10
    """Steps between rows of the CSV loss log (means since the last row)."""
    preview_every: int = 200
    """Steps between preview PNGs (prediction | ground truth); 0 turns them off."""
    precision: str = "auto"
    """Training arithmetic. ``fp32``: float32 everywhere, the reference. ``bf16``: the
    generator under bfloat16 autocast, on any device (CPU included); the spectral-norm
    discriminator and every loss stay in float32 (its power iteration is what low precision
    makes unstable). ``fp16``: the same in float16 with loss scaling, CUDA only. ``auto``:
    ``bf16`` on CUDA, ``fp32`` elsewhere. ``tests/test_renderer_precision.py`` compares bf16 with
    fp32."""

    def __post_init__(self) -> None:
        positive = (
            "image_size", "texture_channels", "base_width", "max_width", "n_down",
            "decoder_features", "background_width", "disc_width", "batch_size",
            "checkpoint_every", "log_every",
        )  # fmt: skip
        for name in positive:
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, int) and v > 0):
                raise InputError(f"renderer config {name}={v!r} must be a positive integer")
        for name in (
            "steps",
            "seed",
            "preview_every",
            "crop_margin",
            "motion_channels",
            "background_finetune_steps",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, int) and v >= 0):
                raise InputError(f"renderer config {name}={v!r} must be an integer >= 0")
        if not self.texture_sizes or any(
            not isinstance(s, int) or s < 2 for s in self.texture_sizes
        ):
            raise InputError(f"texture_sizes={self.texture_sizes!r} must be integers >= 2")
        if self.image_size % self.stride:
            raise InputError(
                f"image_size {self.image_size} must be divisible by 2 ** n_down = {self.stride}"
            )
        if self.gan_mode not in GAN_MODES:
            raise InputError(f"gan_mode must be one of {GAN_MODES}, got {self.gan_mode!r}")
        if any(not isinstance(c, int) or c < 0 for c in self.vgg_channels):
            raise InputError(f"vgg_channels={self.vgg_channels!r} must be integers >= 0")
        if not (isinstance(self.alpha_prior, (int, float)) and math.isfinite(self.alpha_prior)):
            raise InputError(f"renderer config alpha_prior={self.alpha_prior!r} must be finite")
        for name in (
            "w_l1", "w_pyramid", "w_detail", "w_gradient", "w_perceptual", "w_fm", "w_gan", "w_texture",
            "lr_g", "lr_d",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"renderer config {name}={v!r} must be a finite number >= 0")
        check_decay_from(self.lr_decay_from, "renderer")
        check_positive(self.adam_eps, "renderer", "adam_eps")
        check_positive(self.texture_lr_scale, "renderer", "texture_lr_scale")
        if self.precision not in PRECISIONS:
            raise InputError(f"precision must be one of {PRECISIONS}, got {self.precision!r}")
        if not 0.0 < self.body_finetune_fraction <= 1.0:
            raise InputError(
                f"body_finetune_fraction={self.body_finetune_fraction!r} must be in (0, 1]"
            )

    @classmethod
    def from_dict(cls, data: dict) -> RendererConfig:
        """As :meth:`PlainConfig.from_dict`; files from before ``precision`` existed hold
        ``mixed_precision`` (True: ``auto``, False: ``fp32``)."""
        data = dict(data)
        if "mixed_precision" in data:
            old = data.pop("mixed_precision")
            data.setdefault("precision", "auto" if old else "fp32")
        return super().from_dict(data)

    @classmethod
    def from_stored(cls, data: dict) -> RendererConfig:
        """The config of a model file or bundle: fields added since read as the files were
        trained: before ``lr_decay_from`` at constant rates (1.0), before ``adam_eps`` at
        torch's 1e-8, before ``texture_lr_scale`` at one rate, before ``texture_readout``
        without one, before ``background_guide`` unguided, before ``alpha_prior`` with none."""
        old = {
            "lr_decay_from": 1.0,
            "adam_eps": 1e-8,
            "texture_lr_scale": 1.0,
            "texture_readout": False,
            "background_guide": False,
            "alpha_prior": 0.0,
        }
        return cls.from_dict({**old, **data})

    def resolved_precision(self, device_type: str) -> str:
        """``fp32``, ``bf16`` or ``fp16`` on a device of this type (``cpu``, ``cuda``)."""
        if self.precision == "auto":
            return "bf16" if device_type == "cuda" else "fp32"
        if self.precision == "fp16" and device_type != "cuda":
            raise InputError("renderer precision fp16 needs CUDA: use bf16 or fp32 on the CPU")
        return self.precision

    @property
    def stride(self) -> int:
        """Pixels per latent cell: inputs must be a multiple of it per side."""
        return 2**self.n_down

    @property
    def texture_out_channels(self) -> int:
        """Channels sampled from the neural texture (all levels)."""
        return len(self.texture_sizes) * self.texture_channels

    @property
    def in_channels(self) -> int:
        """Network input channels: texture + motion (159 in the paper); without motion, texture
        + the proxy's coverage mask."""
        return self.texture_out_channels + (self.motion_channels if self.use_motion else 1)

    def replace(self, **changes) -> RendererConfig:
        """A copy with some fields changed (validated)."""
        return replace(self, **changes)


#: Named configurations. ``cpu``: trains in minutes on 2 cores at 128 px. ``paper``: 512 px,
#: the published sizes (16 x 16 x 512 latent, 64-channel PatchGAN). ``tiny``: for tests.
PRESETS: dict[str, RendererConfig] = {
    "cpu": RendererConfig(),
    "paper": RendererConfig(
        image_size=512,
        texture_sizes=(512, 256, 128, 64),
        skip_connections=False,
        texture_readout=False,
        alpha_prior=0.0,
        blend_output=False,
        w_pyramid=0.0,
        w_detail=0.0,
        w_gradient=0.0,
        lr_g=1e-4,
        lr_decay_from=1.0,
        texture_lr_scale=1.0,
        base_width=32,
        max_width=512,
        n_down=5,
        decoder_features=32,
        background_width=32,
        disc_width=64,
        steps=100000,
        background_finetune_steps=2000,
        checkpoint_every=1000,
        log_every=50,
        preview_every=1000,
    ),
    "tiny": RendererConfig(
        image_size=32,
        texture_sizes=(32, 16),
        texture_channels=4,
        base_width=8,
        max_width=16,
        n_down=2,
        decoder_features=8,
        background_width=8,
        disc_width=8,
        steps=20,
        background_finetune_steps=5,
        checkpoint_every=5,
        log_every=2,
        preview_every=10,
        crop_margin=4,
    ),
}


def preset(name: str) -> RendererConfig:
    """The named preset; ``InputError`` listing the names for an unknown one."""
    if name not in PRESETS:
        raise InputError(f"unknown renderer preset {name!r}; choose from {sorted(PRESETS)}")
    return PRESETS[name]
