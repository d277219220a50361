"""Losses of the neural renderer: L1, VGG19 perceptual, GAN (hinge or LSGAN), feature matching,
and three that need no weights and ask for fine detail: a Laplacian-pyramid L1, a local
detail-energy L1 and a multi-scale gradient-magnitude similarity.

The perceptual loss needs VGG19 weights, which cannot be downloaded here: give the path of a
torchvision-layout state dict (``torchvision.models.vgg19().state_dict()`` saved with
``torch.save``; only the ``features.N.weight`` / ``features.N.bias`` entries are read). Without a
path, :func:`load_perceptual` returns None and the training log says the loss is off.
:func:`vgg_features` is our own few lines rather than ``torchvision.models.vgg19`` for the same
reason as :mod:`training.inception`'s network: no torchvision version to pin against torch's.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import torch
from torch import nn
from torch.nn import functional as F

from core.errors import InputError
from training.metrics import gradient_magnitude, gradient_similarity, laplacian_energy, luminance

#: torchvision's VGG19 ("E") layer list: conv widths, 0 for a 2x2 max pool.
VGG19_CHANNELS: tuple[int, ...] = (
    64, 64, 0, 128, 128, 0, 256, 256, 256, 256, 0, 512, 512, 512, 512, 0, 512, 512, 512, 512, 0,
)  # fmt: skip
#: The ReLUs whose outputs are compared (after the 1st conv of each block: relu1_1 ... relu5_1)
#: and their weights (pix2pixHD's).
PERCEPTUAL_BLOCK_WEIGHTS: tuple[float, ...] = (1 / 32, 1 / 16, 1 / 8, 1 / 4, 1.0)
_MEAN = (0.485, 0.456, 0.406)
_STD = (0.229, 0.224, 0.225)


def vgg_features(channels: Sequence[int] = VGG19_CHANNELS) -> nn.Sequential:
    """The ``features`` part of a torchvision VGG: conv3x3 + ReLU per width, MaxPool for 0.

    Module indices match torchvision's, so ``features.0.weight`` ... load unchanged.
    """
    layers: list[nn.Module] = []
    c = 3
    for w in channels:
        if w == 0:
            layers.append(nn.MaxPool2d(2, 2))
        else:
            layers += [nn.Conv2d(c, w, 3, padding=1), nn.ReLU(inplace=False)]
            c = w
    return nn.Sequential(*layers)


def _tap_indices(channels: Sequence[int]) -> list[int]:
    """Indices (in ``features``) of the ReLU after the first conv of each pooling block."""
    taps, idx, first = [], 0, True
    for w in channels:
        if w == 0:
            idx += 1
            first = True
            continue
        if first:
            taps.append(idx + 1)
            first = False
        idx += 2
    return taps


class PerceptualLoss(nn.Module):
    """Weighted L1 between VGG activations of prediction and target (frozen VGG).

    Parameters
    ----------
    features : the VGG ``features`` sequential (weights loaded)
    channels : its layer list (to find the taps)
    """

    def __init__(self, features: nn.Sequential, channels: Sequence[int]):
        super().__init__()
        taps = _tap_indices(channels)[: len(PERCEPTUAL_BLOCK_WEIGHTS)]
        self.features = features[: taps[-1] + 1].eval()
        self.taps = taps
        self.weights = PERCEPTUAL_BLOCK_WEIGHTS[-len(taps) :]
        for p in self.features.parameters():
            p.requires_grad_(False)
        self.register_buffer("mean", torch.tensor(_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(_STD).view(1, 3, 1, 1), persistent=False)

    def train(self, mode: bool = True) -> PerceptualLoss:
        super().train(mode)
        self.features.eval()  # always: no dropout / batch norm inside, but keep it fixed
        return self

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """pred, target : (B, 3, H, W) in [0, 1] -> scalar."""
        x = torch.cat([pred, target]).sub(self.mean).div(self.std)
        loss = x.new_zeros(())
        k = 0
        for i, layer in enumerate(self.features):
            x = layer(x)
            if k < len(self.taps) and i == self.taps[k]:
                a, b = x.chunk(2)
                loss = loss + self.weights[k] * F.l1_loss(a, b.detach())
                k += 1
        return loss


def load_vgg_features(
    path: str | os.PathLike, channels: Sequence[int] = VGG19_CHANNELS
) -> nn.Sequential:
    """VGG ``features`` with weights from a torchvision-layout file; ``InputError`` naming it."""
    path = Path(path)
    if not path.is_file():
        raise InputError("VGG weights file not found", path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise InputError(f"cannot read VGG weights: {exc}", path) from None
    if isinstance(state, nn.Module):  # pragma: no cover - weights_only refuses modules
        state = state.state_dict()
    if not isinstance(state, dict):
        raise InputError("VGG weights file must hold a state dict", path)
    features = vgg_features(channels)
    wanted = {f"features.{k}": v for k, v in features.state_dict().items()}
    missing = [k for k in wanted if k not in state]
    if missing:
        raise InputError(
            f"not a torchvision VGG state dict: missing {missing[:3]} (of {len(missing)})", path
        )
    for k, v in wanted.items():
        if tuple(state[k].shape) != tuple(v.shape):
            raise InputError(
                f"{k} has shape {tuple(state[k].shape)}, expected {tuple(v.shape)}", path
            )
    features.load_state_dict({k[len("features.") :]: state[k].float() for k in wanted})
    return features


def load_perceptual(
    path: str | os.PathLike | None, channels: Sequence[int] = ()
) -> PerceptualLoss | None:
    """The perceptual loss from a weights file, or None when ``path`` is empty (loss off)."""
    if not path:
        return None
    channels = tuple(channels) or VGG19_CHANNELS
    return PerceptualLoss(load_vgg_features(path, channels), channels)


def gan_d_loss(real: torch.Tensor, fake: torch.Tensor, mode: str = "hinge") -> torch.Tensor:
    """Discriminator loss on logits of real and fake patches (any shape) -> scalar."""
    if mode == "hinge":
        return F.relu(1 - real).mean() + F.relu(1 + fake).mean()
    if mode == "lsgan":
        return ((real - 1) ** 2).mean() + (fake**2).mean()
    raise InputError(f"unknown GAN mode {mode!r}")


def gan_g_loss(fake: torch.Tensor, mode: str = "hinge") -> torch.Tensor:
    """Generator loss on logits of fake patches -> scalar."""
    if mode == "hinge":
        return -fake.mean()
    if mode == "lsgan":
        return ((fake - 1) ** 2).mean()
    raise InputError(f"unknown GAN mode {mode!r}")


def feature_matching(fake: Sequence[torch.Tensor], real: Sequence[torch.Tensor]) -> torch.Tensor:
    """Mean L1 between discriminator activations of fake and (detached) real inputs -> scalar."""
    loss = fake[0].new_zeros(())
    for a, b in zip(fake, real):
        loss = loss + F.l1_loss(a, b.detach())
    return loss / max(len(fake), 1)


#: 5-tap binomial filter of the Laplacian pyramid (Burt and Adelson 1983).
BINOMIAL5 = (1 / 16, 4 / 16, 6 / 16, 4 / 16, 1 / 16)
#: Levels of :func:`pyramid_l1`: the bands of 1-2, 2-4 and 4-8 px at full resolution.
PYRAMID_LEVELS = 3
#: Window (pixels) of :func:`detail_energy_l1`'s local energy.
DETAIL_WINDOW = 8


def _blur(x: torch.Tensor) -> torch.Tensor:
    """(B, C, H, W) -> the same, blurred by the separable binomial filter (edges replicated)."""
    c = x.shape[1]
    k = torch.tensor(BINOMIAL5, dtype=x.dtype, device=x.device)
    x = F.pad(x, (2, 2, 2, 2), mode="replicate")
    x = F.conv2d(x, k.view(1, 1, 1, 5).expand(c, 1, 1, 5), groups=c)
    return F.conv2d(x, k.view(1, 1, 5, 1).expand(c, 1, 5, 1), groups=c)


def laplacian_bands(x: torch.Tensor, levels: int = PYRAMID_LEVELS) -> list[torch.Tensor]:
    """The band-pass levels of a Laplacian pyramid: (B, C, H, W) -> ``levels`` tensors, the k-th
    (B, C, H / 2**k, W / 2**k): the image at that scale less its blur (sides halved by 2 x 2
    averages, rounding down)."""
    out = []
    for _ in range(levels):
        low = _blur(x)
        out.append(x - low)
        x = F.avg_pool2d(low, 2)
    return out


def pyramid_l1(pred: torch.Tensor, target: torch.Tensor, levels: int = PYRAMID_LEVELS):
    """Sum over the pyramid's levels of the mean L1 between the two images' bands (Lap1,
    Bojanowski et al. 2018, with every band weighted alike): (B, C, H, W) twice -> scalar.

    Plain L1 is dominated by the flat colours; this counts each band of detail as much as the
    image's, so misplaced or missing edges cost as much as a wrong colour. A constant offset
    costs nothing here (L1 sees it)."""
    return sum(
        F.l1_loss(a, b)
        for a, b in zip(laplacian_bands(pred, levels), laplacian_bands(target, levels))
    )


def detail_energy(images: torch.Tensor, window: int = DETAIL_WINDOW) -> torch.Tensor:
    """Local fine-detail energy: (B, 3, H, W) in [0, 1] -> (B, 1, H / window, W / window), the
    mean |Laplacian| (4-neighbour) of the luminance over each window (edges replicated)."""
    y = F.pad(luminance(images), (1, 1, 1, 1), mode="replicate")
    return F.avg_pool2d(laplacian_energy(y), window)


def detail_energy_l1(pred: torch.Tensor, target: torch.Tensor, window: int = DETAIL_WINDOW):
    """Mean L1 between the two images' :func:`detail_energy` maps -> scalar: as much fine detail
    as the target in each window, wherever in it the detail lies. Per-pixel losses pay a blur
    where an edge's place is uncertain; this one charges for the detail the blur removed."""
    return F.l1_loss(detail_energy(pred, window), detail_energy(target, window))


#: Scales of :func:`gradient_similarity_loss`: full, half and quarter resolution.
GRADIENT_SCALES = 3


def _gradient_magnitude(gray: torch.Tensor) -> torch.Tensor:
    """:func:`training.metrics.gradient_magnitude` of (B, 1, H, W) -> (B, 1, H, W): the edges
    replicated, and a tiny floor under the root so that a flat image has a finite gradient."""
    return gradient_magnitude(F.pad(gray, (1, 1, 1, 1), mode="replicate"), eps=1e-12)


def gradient_similarity_loss(
    pred: torch.Tensor, target: torch.Tensor, scales: int = GRADIENT_SCALES
) -> torch.Tensor:
    """Mean over ``scales`` (the images halved by 2 x 2 averages each time) of 1 - the mean
    gradient-magnitude similarity of their luminance (Xue et al. 2014's GMS, its constant for
    [0, 1] images): (B, 3, H, W) twice -> scalar, 0 for the same edges.

    Each pixel's similarity is a ratio, so a faint edge missing or misplaced costs as much as a
    strong one, and an edge drawn where the target is flat costs as much as one left out: a
    per-pixel loss pays a blur there, this one does not."""
    p, t = luminance(pred), luminance(target)
    loss = pred.new_zeros(())
    for k in range(scales):
        if k:
            p, t = F.avg_pool2d(p, 2), F.avg_pool2d(t, 2)
        g_p, g_t = _gradient_magnitude(p), _gradient_magnitude(t)
        loss = loss + (1 - gradient_similarity(g_p, g_t)).mean()
    return loss / scales
