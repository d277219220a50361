"""LPIPS and the temporal metric tLP, from LPIPS weights the user gives as a file.

No weights can be downloaded here (DESIGN, "Things this environment does not have"). Pass the
state dict of the ``lpips`` package's AlexNet model, saved on a machine that has it::

    python -c "import lpips, torch; torch.save(lpips.LPIPS(net='alex').state_dict(), 'lpips-alex.pth')"

:class:`LPIPS` is written to have exactly that layout: the ImageNet AlexNet's five conv
layers as ``net.slice1.0`` (conv 11x11/4, 64), ``net.slice2.3`` (5x5, 192), ``net.slice3.6``
(3x3, 384), ``net.slice4.8`` (3x3, 256) and ``net.slice5.10`` (3x3, 256), with ReLUs and two
3x3/2 max pools between them as in torchvision's ``alexnet().features``; the learned
per-channel weights ``lin0.model.1.weight`` ... ``lin4.model.1.weight`` (1 x C x 1 x 1); and
the input's ``scaling_layer.shift`` / ``scale``. Duplicate ``lins.K.*`` entries (the package
registers its heads twice) are accepted. Without a file every call returns a result whose status
says ``unavailable: no LPIPS weights file given`` and whose value is None: never a made-up
number.

**What the numbers are.**

- LPIPS (Zhang et al. 2018) of two images: each scaled to [-1, 1], shifted and scaled per
  channel, through the five layers; each layer's activations normalised to unit length over
  channels at each pixel, the squared difference weighted per channel by ``lin``, summed over
  channels and averaged over pixels; the five layers summed. 0 for identical images.
- tLP (TecoGAN, Chu et al. 2020): for each consecutive pair of frames, ``|LPIPS(R_t, R_{t+1}) -
  LPIPS(I_t, I_{t+1})|``, R the render and I the ground truth, averaged over the pairs: 0 when
  the render changes from frame to frame as perceptibly as the ground truth does; it grows
  with flicker and with frozen output. Whole frames, as TecoGAN measures it.

``width_scale`` shrinks every layer (tests build a small network, save it and load it through
the same path as real weights); real weights need ``width_scale=1``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F

from core.errors import InputError
from training.weights import load_state, read_state_dict

UNAVAILABLE = "unavailable: no LPIPS weights file given"
#: AlexNet's five conv layers' channels, and their indices in torchvision's ``features``.
CHANNELS = (64, 192, 384, 256, 256)
_INDEX = (0, 3, 6, 8, 10)
#: The ``lpips`` package's input scaling (its ``ScalingLayer``), the defaults of a new module.
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)


class _Lin(nn.Module):
    """A layer's per-channel weights: a 1x1 conv to one channel without bias, key
    ``model.1.weight`` (the package's dropout is ``model.0``, nothing to load)."""

    def __init__(self, channels: int):
        super().__init__()
        self.model = nn.Sequential(nn.Identity(), nn.Conv2d(channels, 1, 1, bias=False))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


class _Scaling(nn.Module):
    def __init__(self):
        super().__init__()
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.shift) / self.scale


class LPIPS(nn.Module):
    """LPIPS on AlexNet (the module docstring); ``forward(a, b)``: (N, 3, H, W) in [0, 1] each,
    H, W >= 32 -> (N,) distances."""

    def __init__(self, width_scale: float = 1.0):
        super().__init__()
        if not 0 < width_scale <= 1:
            raise InputError(f"LPIPS width_scale={width_scale!r} must be in (0, 1]")
        chans = [max(1, round(c * width_scale)) for c in CHANNELS]
        kernels = ((11, 4, 2), (5, 1, 2), (3, 1, 1), (3, 1, 1), (3, 1, 1))
        self.scaling_layer = _Scaling()
        self.net = nn.Module()
        cin = 3
        for k, (cout, (size, stride, pad), index) in enumerate(zip(chans, kernels, _INDEX)):
            conv = nn.Conv2d(cin, cout, size, stride, pad)
            self.net.add_module(f"slice{k + 1}", nn.Sequential())
            getattr(self.net, f"slice{k + 1}").add_module(str(index), conv)
            self.add_module(f"lin{k}", _Lin(cout))
            cin = cout
        self.channels = tuple(chans)

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The five layers' activations (after their ReLUs) of images in [0, 1]."""
        h = self.scaling_layer(2 * x - 1)
        out = []
        for k in range(5):
            if k in (1, 2):  # torchvision's max pools before the second and third convs
                h = F.max_pool2d(h, 3, 2)
            conv = getattr(self.net, f"slice{k + 1}")[0]
            h = F.relu(conv(h))
            out.append(h)
        return out

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        total = 0.0
        for k, (fa, fb) in enumerate(zip(self.features(a), self.features(b))):
            na = fa / (fa.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            nb = fb / (fb.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            total = total + getattr(self, f"lin{k}")((na - nb) ** 2).mean((2, 3))
        return total[:, 0]


def load_lpips(path: str | os.PathLike, width_scale: float = 1.0) -> LPIPS:
    """An :class:`LPIPS` (eval mode) with weights from an ``lpips``-package state dict.

    ``lins.K.*`` duplicates are ignored; any other missing, unexpected or wrongly shaped entry
    raises :class:`InputError` naming the file."""
    state, path = read_state_dict(path, "LPIPS")
    state = {k: v for k, v in state.items() if not k.startswith("lins.")}
    return load_state(
        LPIPS(width_scale), state, path, "an lpips.LPIPS(net='alex')",
        optional=lambda k: k.startswith("scaling_layer."),
        note=f" (width_scale={width_scale})",
    )  # fmt: skip


@dataclass(frozen=True)
class TlpResult:
    """A tLP value, or why there is none: ``value`` (None when unavailable), ``status``
    (``"ok"`` or ``"unavailable: ..."``), ``pairs`` scored."""

    value: float | None
    status: str
    pairs: int

    def to_dict(self) -> dict:
        return {"value": self.value, "status": self.status, "pairs": self.pairs}


def tlp(
    real_pairs: Sequence,
    fake_pairs: Sequence,
    weights: str | os.PathLike | None,
    width_scale: float = 1.0,
) -> TlpResult:
    """tLP (the module docstring) over consecutive pairs of frames.

    real_pairs, fake_pairs : sequences of (2, 3, H, W) float in [0, 1], frames t and t+1 of the
        ground truth and of the render (the same pairs on both sides)
    weights : an ``lpips`` AlexNet state dict file; None or "" -> unavailable result
    """
    if not weights:
        return TlpResult(None, UNAVAILABLE, 0)
    if len(real_pairs) != len(fake_pairs):
        raise InputError(f"tLP needs as many real pairs as rendered, got {len(real_pairs)} and "
                         f"{len(fake_pairs)}")  # fmt: skip
    if not len(real_pairs):
        return TlpResult(None, "unavailable: no consecutive frames", 0)
    net = load_lpips(weights, width_scale)
    real = torch.stack([torch.as_tensor(p).float() for p in real_pairs])  # (P, 2, 3, H, W)
    fake = torch.stack([torch.as_tensor(p).float() for p in fake_pairs])
    with torch.no_grad():
        d_real = net(real[:, 0], real[:, 1])
        d_fake = net(fake[:, 0], fake[:, 1])
    return TlpResult(float((d_fake - d_real).abs().mean()), "ok", len(real))
