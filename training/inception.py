"""FID and a video FID stand-in, from an InceptionV3 whose weights the user gives as a file.

No weights can be downloaded here (DESIGN, "Things this environment does not have"). Pass the
path of torchvision's ImageNet ``inception_v3_google-*.pth`` (``torchvision.models.inception_v3``
weights saved with ``torch.save``): :class:`InceptionV3` is written to have exactly its
state-dict layout (``Conv2d_1a_3x3.conv.weight``, ``Mixed_5b.branch1x1.bn.running_mean``, ...,
``fc.weight``; the auxiliary classifier's ``AuxLogits.*`` entries are ignored). Without a path
every call returns a result whose status says ``unavailable: no Inception weights file given``
and whose value is None: never a made-up number.

Our own definition with torchvision's names rather than ``torchvision.models``: a torchvision
wheel must match torch's exact version and build (the studio pins a CPU torch; the torch-only GPU
machine brings its own), while the user's torchvision weight file loads into this one unchanged
(tested with a file the test writes).

**What the numbers are.**

- FID: the Frechet distance between Gaussians fitted to the 2048-d pool3 features (after the
  global average pool) of the real and the generated images. Images are resized bilinearly to
  299 x 299 and scaled to [-1, 1] (what torchvision's ``transform_input`` does for these
  weights). With torchvision's weights the values rank methods consistently but are not
  identical to the TensorFlow-Inception FID of the paper (``pytorch-fid`` uses a slightly
  different port of the network and its own weights); compare our methods with each other.
- Video FID: **not** FVD. FVD needs an I3D video network whose weights we do not have. Our stand-in
  is the FID of *frame-to-frame feature changes*: for each pair of consecutive frames of a clip,
  ``f(x_{t+1}) - f(x_t)`` with ``f`` the Inception pool3 features; real and generated
  distributions of these 2048-d vectors are compared with the Frechet distance. Appearance is
  left to the plain FID; this one is 0 when the generated frames change like the real ones and
  grows with flicker or frozen output.
- FID is biased for small sample counts (and the 2048 x 2048 covariance is singular below 2049
  images; an ``eps`` offset is added to the diagonals then, as is standard): compare values
  computed on the same number of images.

``width_scale`` shrinks every layer (tests build a small network, save it and load it through
the same path as real weights); real weights need ``width_scale=1``.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from core.errors import InputError
from training.configs import PlainConfig
from training.weights import load_state, read_state_dict

UNAVAILABLE = "unavailable: no Inception weights file given"
#: Regularisation of singular covariances (pytorch-fid's default).
FID_EPS = 1e-6


@dataclass(frozen=True)
class InceptionConfig(PlainConfig):
    """How features are extracted for FID."""

    kind: ClassVar[str] = "inception"

    width_scale: float = 1.0
    """Multiplies every layer's channels (1 for real InceptionV3 weights; small for tests)."""
    image_size: int = 299
    """Images are resized (bilinear) to this square size; 299 for the real network, >= 75."""
    batch_size: int = 32
    """Images per forward pass."""
    device: str = "cpu"
    """Where the network runs ("cpu", "cuda")."""

    def __post_init__(self) -> None:
        if not (isinstance(self.width_scale, (int, float)) and 0 < self.width_scale <= 1):
            raise InputError(f"inception width_scale={self.width_scale!r} must be in (0, 1]")
        if not isinstance(self.image_size, int) or self.image_size < 75:
            raise InputError(f"inception image_size={self.image_size!r} must be an int >= 75")
        if not isinstance(self.batch_size, int) or self.batch_size < 1:
            raise InputError(f"inception batch_size={self.batch_size!r} must be >= 1")


# --------------------------------------------------------------------------------------------
# The network (torchvision's module names, written from the InceptionV3 paper's figures)


class BasicConv2d(nn.Module):
    """conv (no bias) -> batch norm (eps 1e-3) -> ReLU; keys ``conv.*``, ``bn.*``."""

    def __init__(self, cin: int, cout: int, kernel, stride=1, padding=0):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, kernel, stride, padding, bias=False)
        self.bn = nn.BatchNorm2d(cout, eps=0.001)
        self.out_channels = cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.bn(self.conv(x)))


class _Block(nn.Module):
    """A mixed block: branches run on the same input, outputs concatenated on channels."""

    out_channels: int


class InceptionA(_Block):
    """Mixed_5b/c/d (35 x 35): 1x1 | 1x1-5x5 | 1x1-3x3-3x3 | avgpool-1x1."""

    def __init__(self, cin: int, pool: int, w):
        super().__init__()
        self.branch1x1 = BasicConv2d(cin, w(64), 1)
        self.branch5x5_1 = BasicConv2d(cin, w(48), 1)
        self.branch5x5_2 = BasicConv2d(w(48), w(64), 5, padding=2)
        self.branch3x3dbl_1 = BasicConv2d(cin, w(64), 1)
        self.branch3x3dbl_2 = BasicConv2d(w(64), w(96), 3, padding=1)
        self.branch3x3dbl_3 = BasicConv2d(w(96), w(96), 3, padding=1)
        self.branch_pool = BasicConv2d(cin, w(pool), 1)
        self.out_channels = w(64) + w(64) + w(96) + w(pool)

    def forward(self, x):
        a = self.branch1x1(x)
        b = self.branch5x5_2(self.branch5x5_1(x))
        c = self.branch3x3dbl_3(self.branch3x3dbl_2(self.branch3x3dbl_1(x)))
        d = self.branch_pool(F.avg_pool2d(x, 3, 1, 1))
        return torch.cat([a, b, c, d], 1)


class InceptionB(_Block):
    """Mixed_6a (35 -> 17): 3x3/2 | 1x1-3x3-3x3/2 | maxpool/2."""

    def __init__(self, cin: int, w):
        super().__init__()
        self.branch3x3 = BasicConv2d(cin, w(384), 3, stride=2)
        self.branch3x3dbl_1 = BasicConv2d(cin, w(64), 1)
        self.branch3x3dbl_2 = BasicConv2d(w(64), w(96), 3, padding=1)
        self.branch3x3dbl_3 = BasicConv2d(w(96), w(96), 3, stride=2)
        self.out_channels = w(384) + w(96) + cin

    def forward(self, x):
        a = self.branch3x3(x)
        b = self.branch3x3dbl_3(self.branch3x3dbl_2(self.branch3x3dbl_1(x)))
        return torch.cat([a, b, F.max_pool2d(x, 3, 2)], 1)


class InceptionC(_Block):
    """Mixed_6b..e (17 x 17): factorised 7x7 convolutions (1x7 and 7x1)."""

    def __init__(self, cin: int, c7: int, w):
        super().__init__()
        c7 = w(c7)
        row, col = ((1, 7), (0, 3)), ((7, 1), (3, 0))
        self.branch1x1 = BasicConv2d(cin, w(192), 1)
        self.branch7x7_1 = BasicConv2d(cin, c7, 1)
        self.branch7x7_2 = BasicConv2d(c7, c7, row[0], padding=row[1])
        self.branch7x7_3 = BasicConv2d(c7, w(192), col[0], padding=col[1])
        self.branch7x7dbl_1 = BasicConv2d(cin, c7, 1)
        self.branch7x7dbl_2 = BasicConv2d(c7, c7, col[0], padding=col[1])
        self.branch7x7dbl_3 = BasicConv2d(c7, c7, row[0], padding=row[1])
        self.branch7x7dbl_4 = BasicConv2d(c7, c7, col[0], padding=col[1])
        self.branch7x7dbl_5 = BasicConv2d(c7, w(192), row[0], padding=row[1])
        self.branch_pool = BasicConv2d(cin, w(192), 1)
        self.out_channels = 4 * w(192)

    def forward(self, x):
        a = self.branch1x1(x)
        b = self.branch7x7_3(self.branch7x7_2(self.branch7x7_1(x)))
        c = self.branch7x7dbl_1(x)
        for layer in (self.branch7x7dbl_2, self.branch7x7dbl_3, self.branch7x7dbl_4):
            c = layer(c)
        c = self.branch7x7dbl_5(c)
        d = self.branch_pool(F.avg_pool2d(x, 3, 1, 1))
        return torch.cat([a, b, c, d], 1)


class InceptionD(_Block):
    """Mixed_7a (17 -> 8): 1x1-3x3/2 | 1x1-1x7-7x1-3x3/2 | maxpool/2."""

    def __init__(self, cin: int, w):
        super().__init__()
        self.branch3x3_1 = BasicConv2d(cin, w(192), 1)
        self.branch3x3_2 = BasicConv2d(w(192), w(320), 3, stride=2)
        self.branch7x7x3_1 = BasicConv2d(cin, w(192), 1)
        self.branch7x7x3_2 = BasicConv2d(w(192), w(192), (1, 7), padding=(0, 3))
        self.branch7x7x3_3 = BasicConv2d(w(192), w(192), (7, 1), padding=(3, 0))
        self.branch7x7x3_4 = BasicConv2d(w(192), w(192), 3, stride=2)
        self.out_channels = w(320) + w(192) + cin

    def forward(self, x):
        a = self.branch3x3_2(self.branch3x3_1(x))
        b = self.branch7x7x3_1(x)
        for layer in (self.branch7x7x3_2, self.branch7x7x3_3, self.branch7x7x3_4):
            b = layer(b)
        return torch.cat([a, b, F.max_pool2d(x, 3, 2)], 1)


class InceptionE(_Block):
    """Mixed_7b/c (8 x 8): expanded filter bank with parallel 1x3 and 3x1 outputs."""

    def __init__(self, cin: int, w):
        super().__init__()
        self.branch1x1 = BasicConv2d(cin, w(320), 1)
        self.branch3x3_1 = BasicConv2d(cin, w(384), 1)
        self.branch3x3_2a = BasicConv2d(w(384), w(384), (1, 3), padding=(0, 1))
        self.branch3x3_2b = BasicConv2d(w(384), w(384), (3, 1), padding=(1, 0))
        self.branch3x3dbl_1 = BasicConv2d(cin, w(448), 1)
        self.branch3x3dbl_2 = BasicConv2d(w(448), w(384), 3, padding=1)
        self.branch3x3dbl_3a = BasicConv2d(w(384), w(384), (1, 3), padding=(0, 1))
        self.branch3x3dbl_3b = BasicConv2d(w(384), w(384), (3, 1), padding=(1, 0))
        self.branch_pool = BasicConv2d(cin, w(192), 1)
        self.out_channels = w(320) + 4 * w(384) + w(192)

    def forward(self, x):
        a = self.branch1x1(x)
        b = self.branch3x3_1(x)
        b = torch.cat([self.branch3x3_2a(b), self.branch3x3_2b(b)], 1)
        c = self.branch3x3dbl_2(self.branch3x3dbl_1(x))
        c = torch.cat([self.branch3x3dbl_3a(c), self.branch3x3dbl_3b(c)], 1)
        d = self.branch_pool(F.avg_pool2d(x, 3, 1, 1))
        return torch.cat([a, b, c, d], 1)


class InceptionV3(nn.Module):
    """InceptionV3 with torchvision's parameter names (no auxiliary classifier).

    Parameters
    ----------
    width_scale : every layer has ``max(1, round(c * width_scale))`` channels (1: the real one)
    num_classes : outputs of ``fc`` (1000 for the ImageNet weights)

    ``features(x)``: x (B, 3, H, W) already scaled to [-1, 1], H, W >= 75 -> (B, feature_dim)
    pool3 features (2048-d at ``width_scale=1``).
    """

    def __init__(self, width_scale: float = 1.0, num_classes: int = 1000):
        super().__init__()

        def w(c: int) -> int:
            return max(1, round(c * width_scale))

        self.width_scale = width_scale
        self.Conv2d_1a_3x3 = BasicConv2d(3, w(32), 3, stride=2)
        self.Conv2d_2a_3x3 = BasicConv2d(w(32), w(32), 3)
        self.Conv2d_2b_3x3 = BasicConv2d(w(32), w(64), 3, padding=1)
        self.Conv2d_3b_1x1 = BasicConv2d(w(64), w(80), 1)
        self.Conv2d_4a_3x3 = BasicConv2d(w(80), w(192), 3)
        self.Mixed_5b = InceptionA(w(192), 32, w)
        self.Mixed_5c = InceptionA(self.Mixed_5b.out_channels, 64, w)
        self.Mixed_5d = InceptionA(self.Mixed_5c.out_channels, 64, w)
        self.Mixed_6a = InceptionB(self.Mixed_5d.out_channels, w)
        c = self.Mixed_6a.out_channels
        self.Mixed_6b = InceptionC(c, 128, w)
        self.Mixed_6c = InceptionC(c, 160, w)
        self.Mixed_6d = InceptionC(c, 160, w)
        self.Mixed_6e = InceptionC(c, 192, w)
        self.Mixed_7a = InceptionD(self.Mixed_6e.out_channels, w)
        self.Mixed_7b = InceptionE(self.Mixed_7a.out_channels, w)
        self.Mixed_7c = InceptionE(self.Mixed_7b.out_channels, w)
        self.feature_dim = self.Mixed_7c.out_channels
        self.fc = nn.Linear(self.feature_dim, num_classes)

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) in [-1, 1] -> (B, feature_dim) pool3 features."""
        x = self.Conv2d_2b_3x3(self.Conv2d_2a_3x3(self.Conv2d_1a_3x3(x)))
        x = F.max_pool2d(x, 3, 2)
        x = F.max_pool2d(self.Conv2d_4a_3x3(self.Conv2d_3b_1x1(x)), 3, 2)
        for name in (
            "Mixed_5b", "Mixed_5c", "Mixed_5d", "Mixed_6a", "Mixed_6b", "Mixed_6c", "Mixed_6d",
            "Mixed_6e", "Mixed_7a", "Mixed_7b", "Mixed_7c",
        ):  # fmt: skip
            x = getattr(self, name)(x)
        return F.adaptive_avg_pool2d(x, 1).flatten(1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Class logits (B, num_classes) (eval mode; no dropout, no auxiliary head)."""
        return self.fc(self.features(x))


def load_inception(
    path: str | os.PathLike, width_scale: float = 1.0, device: str = "cpu"
) -> InceptionV3:
    """An :class:`InceptionV3` (eval mode) with weights from a torchvision-layout file.

    ``AuxLogits.*`` entries are ignored, missing ``num_batches_tracked`` entries tolerated; any
    other missing, unexpected or wrongly shaped entry raises :class:`InputError` naming the file.
    """
    state, path = read_state_dict(path, "Inception")
    fc = state.get("fc.weight")
    net = InceptionV3(width_scale, num_classes=1000 if fc is None else int(fc.shape[0]))
    state = {k: v for k, v in state.items() if not k.startswith("AuxLogits.")}
    load_state(
        net, state, path, "a torchvision InceptionV3",
        optional=lambda k: k.endswith("num_batches_tracked"),
        note=f" (width_scale={width_scale})",
    )  # fmt: skip
    return net.eval().to(device)


# --------------------------------------------------------------------------------------------
# Features and the Frechet distance


def _batches(images) -> Iterable[torch.Tensor]:
    if isinstance(images, torch.Tensor):
        yield images
    else:
        yield from images


@torch.no_grad()
def extract_features(net: InceptionV3, images, config: InceptionConfig | None = None) -> np.ndarray:
    """Pool3 features of images.

    Parameters
    ----------
    net : InceptionV3 (eval mode)
    images : (N, 3, H, W) float in [0, 1], or an iterable of such batches
    config : resize size, batch size, device

    Returns
    -------
    (N, feature_dim) float64
    """
    cfg = config or InceptionConfig()
    out = []
    for batch in _batches(images):
        batch = torch.as_tensor(batch)
        if batch.dim() != 4 or batch.shape[1] != 3:
            raise InputError(f"images must be (N, 3, H, W), got {tuple(batch.shape)}")
        for i in range(0, len(batch), cfg.batch_size):
            x = batch[i : i + cfg.batch_size].to(cfg.device, torch.float32)
            x = F.interpolate(
                x, size=(cfg.image_size, cfg.image_size), mode="bilinear", align_corners=False
            )
            out.append(net.features(x * 2 - 1).double().cpu())
    if not out:
        return np.zeros((0, net.feature_dim))
    return torch.cat(out).numpy()


def frechet_distance(
    mu1: np.ndarray, sigma1: np.ndarray, mu2: np.ndarray, sigma2: np.ndarray, eps: float = FID_EPS
) -> float:
    """``|mu1 - mu2|^2 + tr(S1 + S2 - 2 (S1 S2)^(1/2))``.

    mu : (D,) float64; sigma : (D, D) float64. When scipy reports the product singular (fewer
    samples than dimensions) or its square root is not finite, ``eps`` is added to both
    diagonals (in the traces too: the result is the distance of those regularised Gaussians,
    never negative); a small imaginary part from ``sqrtm``'s numerical error is dropped (a large
    one raises ``ValueError``).
    """
    from scipy import linalg

    mu1, mu2 = np.atleast_1d(mu1).astype(np.float64), np.atleast_1d(mu2).astype(np.float64)
    s1, s2 = np.atleast_2d(sigma1).astype(np.float64), np.atleast_2d(sigma2).astype(np.float64)
    diff = mu1 - mu2
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", linalg.LinAlgWarning)
        covmean = linalg.sqrtm(s1 @ s2)
    singular = any(issubclass(w.category, linalg.LinAlgWarning) for w in caught)
    if singular or not np.isfinite(covmean).all():
        offset = np.eye(len(s1)) * eps
        s1, s2 = s1 + offset, s2 + offset  # the distance of the regularised Gaussians (>= 0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", linalg.LinAlgWarning)
            covmean = linalg.sqrtm(s1 @ s2)
    if np.iscomplexobj(covmean):
        if not np.allclose(np.diagonal(covmean).imag, 0, atol=1e-3):
            raise ValueError(
                f"imaginary component {np.max(np.abs(covmean.imag)):.3g} in the FID square root"
            )
        covmean = covmean.real
    return float(diff @ diff + np.trace(s1) + np.trace(s2) - 2 * np.trace(covmean))


@dataclass(frozen=True)
class FidResult:
    """An FID (or video-FID) value, or why there is none.

    Attributes
    ----------
    value : the distance, or None when unavailable
    status : ``"ok"`` or ``"unavailable: ..."``
    n_real, n_fake : feature vectors on each side
    """

    value: float | None
    status: str
    n_real: int
    n_fake: int

    def to_dict(self) -> dict:
        return {
            "value": self.value,
            "status": self.status,
            "n_real": self.n_real,
            "n_fake": self.n_fake,
        }


def fid_from_features(real: np.ndarray, fake: np.ndarray) -> FidResult:
    """FID of two feature sets (N, D) float64; unavailable with fewer than 2 on either side."""
    if len(real) < 2 or len(fake) < 2:
        return FidResult(
            None, "unavailable: need at least 2 feature vectors per set", len(real), len(fake)
        )
    value = frechet_distance(
        real.mean(0), np.cov(real, rowvar=False), fake.mean(0), np.cov(fake, rowvar=False)
    )
    if not math.isfinite(value):  # pragma: no cover - sqrtm failure
        return FidResult(None, "unavailable: non-finite distance", len(real), len(fake))
    return FidResult(max(value, 0.0), "ok", len(real), len(fake))


def _network(weights, config: InceptionConfig) -> InceptionV3 | None:
    if not weights:
        return None
    return load_inception(weights, config.width_scale, config.device)


def fid(
    real, fake, weights: str | os.PathLike | None, config: InceptionConfig | None = None
) -> FidResult:
    """FID between real and generated images.

    Parameters
    ----------
    real, fake : (N, 3, H, W) float in [0, 1] or iterables of such batches
    weights : torchvision InceptionV3 weights file; None or "" -> unavailable result
    config : InceptionConfig

    Returns
    -------
    FidResult
    """
    cfg = config or InceptionConfig()
    net = _network(weights, cfg)
    if net is None:
        return FidResult(None, UNAVAILABLE, 0, 0)
    return fid_from_features(extract_features(net, real, cfg), extract_features(net, fake, cfg))


def clip_feature_changes(
    net: InceptionV3, clips: Sequence, config: InceptionConfig | None = None
) -> np.ndarray:
    """``f(x_{t+1}) - f(x_t)`` over the consecutive frames of each clip.

    clips : sequence of (T_i, 3, H, W) float tensors in [0, 1] -> (sum(T_i - 1), D) float64.
    """
    out = []
    for clip in clips:
        f = extract_features(net, clip, config)
        out.append(f[1:] - f[:-1])
    return np.concatenate(out) if out else np.zeros((0, net.feature_dim))


def video_fid(
    real_clips: Sequence,
    fake_clips: Sequence,
    weights: str | os.PathLike | None,
    config: InceptionConfig | None = None,
) -> FidResult:
    """The video-FID stand-in (module docstring): Frechet distance of frame-to-frame Inception
    feature changes.

    real_clips, fake_clips : sequences of (T_i, 3, H, W) float in [0, 1], consecutive frames of a
    clip in order (the same clips on both sides). None or "" weights -> unavailable result.
    """
    cfg = config or InceptionConfig()
    net = _network(weights, cfg)
    if net is None:
        return FidResult(None, UNAVAILABLE, 0, 0)
    return fid_from_features(
        clip_feature_changes(net, real_clips, cfg), clip_feature_changes(net, fake_clips, cfg)
    )
