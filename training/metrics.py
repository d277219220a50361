"""Image-quality metrics of the evaluation: MSE, PSNR, SSIM, their garment-masked versions, two
measures that see fine detail (GMSD and a detail ratio, on the garment) and a temporal-stability
(flicker) measure, plus :class:`FrameMetrics`, which collects per-frame values
over batches and summarises them as ``{metric: {"mean", "std", "n"}}``.

Images are ``(N, 3, H, W)`` float tensors in [0, 1] (any float dtype; everything is computed in
float64 on the CPU or the tensors' device). Masks are ``(N, 1, H, W)``, 1 in the region that
counts (the garment), 0 elsewhere; values in between weight the pixel.

**Scales and conventions.**

- MSE is the plain per-frame mean squared error with pixel values in [0, 1], averaged over
  pixels and channels. The paper's table (MSE 0.116 ours / 0.204 DNR / 0.591 Pix2Pix) is on an
  unstated scale (probably x100, or [0, 255] values divided by something); our figures are not
  rescaled to match it.
- PSNR is ``10 log10(1 / MSE)`` dB, capped at :data:`PSNR_CAP_DB` (100 dB): identical images
  give exactly 100, never ``inf``, so summaries stay valid JSON.
- SSIM follows Wang et al. 2004: 11 x 11 Gaussian window (sigma 1.5), ``K1 = 0.01``,
  ``K2 = 0.03``, dynamic range 1, population (co)variances, the window applied only where it
  fits inside the image ("valid", as in the authors' MATLAB code); computed per channel and
  averaged over R, G, B. Images must be at least 11 px per side. The masked SSIM averages the
  SSIM map over the mask's pixels at the centres of those windows.
- Masked metrics of a frame with an empty mask are NaN; :class:`FrameMetrics` leaves such frames
  out and counts only the others (``n``), so an all-empty metric reports ``n = 0`` and
  ``mean = std = None``.
- Our own SSIM, not a library's: the garment-region SSIM needs the SSIM map of the valid
  windows, which pytorch-msssim does not return. Its full-frame SSIM equals ours within 1e-6
  (``tests/test_metrics.py``, pytorch-msssim a test dependency), and :func:`ssim_reference` (a
  plain loop over windows) checks ours to 1e-10.
- GMSD, gradient magnitude similarity deviation (Xue, Zhang, Mou, Bovik 2014), on luminance
  (BT.601): Prewitt gradients (3 x 3, divided by 3), the similarity map
  ``(2 g_r g_d + c) / (g_r^2 + g_d^2 + c)`` with ``c`` = 170 / 255^2 (the paper's 170 on [0, 255]),
  and its standard deviation: 0 for identical images, larger where edges are lost, blurred or
  moved. No 2x average pooling first: that pooling suits the paper's 512 px images, and at 128 px
  it would halve the frill tiers this measure is here to see. Masked: the weighted standard
  deviation over the mask's pixels.
- Detail ratio: the render's mean |Laplacian| of luminance (4-neighbour, 3 x 3, inner pixels)
  over the ground truth's, on the same pixels: 1 is as much fine detail, below 1 blur, above 1
  noise or ringing. It says nothing about where the detail is, which is why GMSD stands beside
  it. NaN where the ground truth has no detail at all.
- Flicker (temporal stability) of consecutive frames t, t+1 of one clip:
  ``mean |(R_{t+1} - R_t) - (I_{t+1} - I_t)|`` over pixels and channels: how much the rendering
  changes beyond what the ground truth changes (0 for a perfect or a perfectly consistently
  wrong rendering). Masked: over the union of the two frames' masks.
- tOF (TecoGAN, Chu et al. 2020) of consecutive frames t, t+1 of one clip: the optical flow
  from frame t to t+1 of the rendering and of the ground truth, each by OpenCV's Farneback method
  on the frames' luminance (8 bit; pyramid scale 0.5, 3 levels, 15 px window, 3 iterations,
  polynomial neighbourhood 5 with sigma 1.2, as TecoGAN's code calls it), and the mean of
  ``|F_R - F_I|`` over pixels and both flow components, in pixels: 0 where the rendering moves
  as the ground truth does, whatever its colours. Masked: over the union of the two frames'
  masks. It needs no downloaded weights.
"""

from __future__ import annotations

import math
from collections.abc import Hashable

import cv2  # opencv-python-headless: the optical flow of tOF
import numpy as np
import torch
from torch.nn import functional as F

from core.errors import InputError

#: PSNR of identical images (and the ceiling of every PSNR), in dB.
PSNR_CAP_DB = 100.0
#: SSIM window: side, Gaussian sigma, constants (Wang et al. 2004).
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
#: Metrics collected by :class:`FrameMetrics`, in report order.
METRICS = (
    "mse", "psnr", "ssim", "mse_masked", "psnr_masked", "ssim_masked", "gmsd_masked",
    "gms_masked", "detail_masked", "flicker", "flicker_masked", "tof_masked",
)  # fmt: skip
#: Farneback's settings for tOF (pyr_scale, levels, winsize, iterations, poly_n, poly_sigma,
#: flags): TecoGAN's.
FARNEBACK = (0.5, 3, 15, 3, 5, 1.2, 0)
#: GMSD's stabilising constant for pixel values in [0, 1] (170 on [0, 255]).
GMSD_C = 170.0 / 255.0**2
#: Luminance weights (ITU-R BT.601), as GMSD's authors convert colour images.
LUMA = (0.299, 0.587, 0.114)


def _check_images(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None):
    pred, target = torch.as_tensor(pred), torch.as_tensor(target)
    if pred.dim() != 4 or pred.shape[1] != 3:
        raise InputError(f"images must be (N, 3, H, W), got {tuple(pred.shape)}")
    if pred.shape != target.shape:
        raise InputError(
            f"prediction {tuple(pred.shape)} and ground truth {tuple(target.shape)} differ"
        )
    pred, target = pred.double(), target.double()
    if mask is not None:
        mask = torch.as_tensor(mask)
        want = (pred.shape[0], 1, *pred.shape[2:])
        if tuple(mask.shape) != want:
            raise InputError(f"mask must be {want}, got {tuple(mask.shape)}")
        mask = mask.to(pred.device).double()
    return pred, target, mask


def _masked_mean(x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Per-image mean of (N, C, H, W) ``x`` (over C, H, W), weighted by (N, 1, H, W) ``mask``;
    NaN where the mask is empty -> (N,) float64."""
    if mask is None:
        return x.flatten(1).mean(1)
    w = mask.expand_as(x).flatten(1)
    total = w.sum(1)
    s = (x.flatten(1) * w).sum(1)
    return torch.where(total > 0, s / total.clamp_min(1e-300), torch.full_like(s, math.nan))


def mse(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Per-frame mean squared error.

    Parameters
    ----------
    pred, target : (N, 3, H, W) float in [0, 1]
    mask : (N, 1, H, W) float or None (whole image)

    Returns
    -------
    (N,) float64; NaN for a frame whose mask is empty
    """
    pred, target, mask = _check_images(pred, target, mask)
    return _masked_mean((pred - target) ** 2, mask)


def psnr_from_mse(err: torch.Tensor, cap_db: float = PSNR_CAP_DB) -> torch.Tensor:
    """``10 log10(1 / mse)`` capped at ``cap_db``; NaN stays NaN. (N,) -> (N,) float64."""
    err = torch.as_tensor(err).double()
    db = 10 * torch.log10(1.0 / err.clamp_min(10 ** (-cap_db / 10)))
    return torch.where(torch.isnan(err), err, db.clamp(max=cap_db))


def psnr(
    pred: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor | None = None,
    cap_db: float = PSNR_CAP_DB,
) -> torch.Tensor:
    """Per-frame PSNR in dB (pixel range 1), capped at ``cap_db``: (N,) float64."""
    return psnr_from_mse(mse(pred, target, mask), cap_db)


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> torch.Tensor:
    """Normalised 1-D Gaussian: (size,) float64, sums to 1."""
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def ssim_map(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The SSIM map, averaged over R, G, B (separable Gaussian convolutions, float64).

    Parameters
    ----------
    pred, target : (N, 3, H, W) float in [0, 1], H and W >= 11

    Returns
    -------
    (N, 1, H - 10, W - 10) float64: SSIM of the window centred on each pixel that has a full
    window inside the image (pixel (i + 5, j + 5) of the input for map entry (i, j))
    """
    pred, target, _ = _check_images(pred, target, None)
    n, c, h, w = pred.shape
    if min(h, w) < SSIM_WINDOW:
        raise InputError(f"SSIM needs images of at least {SSIM_WINDOW} px, got {h} x {w}")
    g = gaussian_window().to(pred.device)
    gx = g.view(1, 1, 1, -1).expand(c, 1, 1, -1)
    gy = g.view(1, 1, -1, 1).expand(c, 1, -1, 1)

    def blur(x: torch.Tensor) -> torch.Tensor:
        return F.conv2d(F.conv2d(x, gx, groups=c), gy, groups=c)

    mu_x, mu_y = blur(pred), blur(target)
    sxx = blur(pred * pred) - mu_x**2
    syy = blur(target * target) - mu_y**2
    sxy = blur(pred * target) - mu_x * mu_y
    c1, c2 = SSIM_K1**2, SSIM_K2**2
    s = ((2 * mu_x * mu_y + c1) * (2 * sxy + c2)) / ((mu_x**2 + mu_y**2 + c1) * (sxx + syy + c2))
    return s.mean(1, keepdim=True)


def ssim(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Per-frame SSIM (mean of :func:`ssim_map`, within ``mask`` when given): (N,) float64.

    The mask (N, 1, H, W) is cropped to the window centres (5 px off each side); a frame whose
    cropped mask is empty gives NaN.
    """
    pred, target, mask = _check_images(pred, target, mask)
    m = ssim_map(pred, target)
    if mask is not None:
        r = SSIM_WINDOW // 2
        mask = mask[:, :, r : mask.shape[2] - r, r : mask.shape[3] - r]
    return _masked_mean(m, mask)


def ssim_reference(pred: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Slow, obvious SSIM (STYLE 6): a Python loop over windows, for tests.

    pred, target : (N, 3, H, W) float in [0, 1] -> (N,) float64.
    """
    pred, target = np.asarray(pred, np.float64), np.asarray(target, np.float64)
    g = gaussian_window().numpy()
    w2 = np.outer(g, g)
    k = SSIM_WINDOW
    c1, c2 = SSIM_K1**2, SSIM_K2**2
    n, c, h, w = pred.shape
    out = np.zeros(n)
    for i in range(n):
        values = []
        for y in range(h - k + 1):
            for x in range(w - k + 1):
                per_channel = []
                for ch in range(c):
                    a = pred[i, ch, y : y + k, x : x + k]
                    b = target[i, ch, y : y + k, x : x + k]
                    ma, mb = (w2 * a).sum(), (w2 * b).sum()
                    va = (w2 * (a - ma) ** 2).sum()
                    vb = (w2 * (b - mb) ** 2).sum()
                    cov = (w2 * (a - ma) * (b - mb)).sum()
                    per_channel.append(
                        ((2 * ma * mb + c1) * (2 * cov + c2))
                        / ((ma**2 + mb**2 + c1) * (va + vb + c2))
                    )
                values.append(np.mean(per_channel))
        out[i] = np.mean(values)
    return out


def luminance(images: torch.Tensor) -> torch.Tensor:
    """(N, 3, H, W) -> (N, 1, H, W): BT.601 luma, in the images' dtype."""
    w = torch.tensor(LUMA, dtype=images.dtype, device=images.device).view(1, 3, 1, 1)
    return (images * w).sum(1, keepdim=True)


def _inner(mask: torch.Tensor | None) -> torch.Tensor | None:
    """A mask cropped to the pixels a 3 x 3 filter reaches without padding."""
    return None if mask is None else mask[:, :, 1:-1, 1:-1]


def gradient_magnitude(gray: torch.Tensor, eps: float = 0.0) -> torch.Tensor:
    """Prewitt gradient magnitude of (N, 1, H, W) -> (N, 1, H - 2, W - 2) (inner pixels).

    ``eps`` goes under the root: a loss that back-propagates through a flat image needs it
    above 0 (the root's derivative is infinite at 0); the metric keeps 0."""
    k = torch.tensor([[1.0, 0.0, -1.0]] * 3, dtype=gray.dtype, device=gray.device) / 3.0
    gx = F.conv2d(gray, k.view(1, 1, 3, 3))
    gy = F.conv2d(gray, k.t().reshape(1, 1, 3, 3))
    return torch.sqrt(gx**2 + gy**2 + eps)


def gradient_similarity(g_pred: torch.Tensor, g_target: torch.Tensor) -> torch.Tensor:
    """Xue et al.'s per-pixel gradient magnitude similarity (GMS) of two gradient magnitude
    maps of one shape, with ``GMSD_C`` for [0, 1] images: 1 where they agree, towards 0 where
    one has an edge the other lacks."""
    return (2 * g_pred * g_target + GMSD_C) / (g_pred**2 + g_target**2 + GMSD_C)


def _gms_map(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None):
    """The checked images' GMS map (N, 1, H - 2, W - 2) and the mask cropped to it."""
    pred, target, mask = _check_images(pred, target, mask)
    g_pred, g_target = (gradient_magnitude(luminance(x)) for x in (pred, target))
    return gradient_similarity(g_pred, g_target), _inner(mask)


def gmsd(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Per-frame gradient magnitude similarity deviation (lower is better, 0 = same edges).

    Parameters
    ----------
    pred, target : (N, 3, H, W) float in [0, 1], H, W >= 3
    mask : (N, 1, H, W) or None; cropped to the inner pixels the gradients reach

    Returns
    -------
    (N,) float64; NaN for a frame whose mask is empty
    """
    gms, inner = _gms_map(pred, target, mask)
    mean = _masked_mean(gms, inner).view(-1, 1, 1, 1)
    return torch.sqrt(_masked_mean((gms - mean) ** 2, inner))


def gms_deficit(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Per-frame mean gradient magnitude similarity deficit, ``1 - mean(GMS)`` (Xue et al.'s
    GMSM, as a deficit: lower is better, 0 = the same edges).

    GMSD is the standard deviation of the same map, so it scores how unevenly the edges are
    missed, not how many: blurring a render with some edges in place and some a pixel off
    lowers its GMSD (every edge is then missed alike) and raises this mean
    (``tests/test_metrics.py``). The two stand side by side in the report.

    Parameters
    ----------
    pred, target : (N, 3, H, W) float in [0, 1], H, W >= 3
    mask : (N, 1, H, W) or None; cropped to the inner pixels the gradients reach

    Returns
    -------
    (N,) float64 in [0, 1]; NaN for a frame whose mask is empty
    """
    gms, inner = _gms_map(pred, target, mask)
    return 1 - _masked_mean(gms, inner)


def laplacian_energy(gray: torch.Tensor) -> torch.Tensor:
    """|4-neighbour Laplacian| of (N, 1, H, W) -> (N, 1, H - 2, W - 2) (inner pixels)."""
    k = torch.tensor(
        [[0.0, 1.0, 0.0], [1.0, -4.0, 1.0], [0.0, 1.0, 0.0]], dtype=gray.dtype, device=gray.device
    )
    return F.conv2d(gray, k.view(1, 1, 3, 3)).abs()


def detail_ratio(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Per-frame fine-detail ratio: mean |Laplacian| of the render over the ground truth's.

    Parameters
    ----------
    pred, target : (N, 3, H, W) float in [0, 1], H, W >= 3
    mask : (N, 1, H, W) or None (the same pixels for both images)

    Returns
    -------
    (N,) float64: 1 = as much detail, < 1 blurred, > 1 noisier; NaN for an empty mask or a
    ground truth with no detail there
    """
    pred, target, mask = _check_images(pred, target, mask)
    inner = _inner(mask)
    e_p = _masked_mean(laplacian_energy(luminance(pred)), inner)
    e_t = _masked_mean(laplacian_energy(luminance(target)), inner)
    return torch.where(e_t > 0, e_p / e_t.clamp_min(1e-300), torch.full_like(e_t, math.nan))


def flicker(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Temporal instability of consecutive frames of one clip.

    Parameters
    ----------
    pred, target : (N, 3, H, W) float in [0, 1], frames 0 .. N-1 in order
    mask : (N, 1, H, W) or None; pair (t, t+1) uses the union (max) of the two frames' masks

    Returns
    -------
    (N - 1,) float64: ``mean |(R_{t+1} - R_t) - (I_{t+1} - I_t)|``; NaN for an empty mask;
    empty when N < 2
    """
    pred, target, mask = _check_images(pred, target, mask)
    return _pair_mean((pred[1:] - pred[:-1]) - (target[1:] - target[:-1]), mask)


def _pair_mean(d: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Mean |d| of each consecutive pair's (N - 1, C, H, W) difference, over the union (max) of
    the pair's two (N, 1, H, W) masks (or every pixel): (N - 1,) float64."""
    pair_mask = None if mask is None else torch.maximum(mask[1:], mask[:-1])
    return _masked_mean(d.abs(), pair_mask)


def optical_flow(frames: torch.Tensor) -> torch.Tensor:
    """Farneback flow from each frame to the next (:data:`FARNEBACK`), on 8-bit luminance:
    frames (N, 3, H, W) in [0, 1] -> (N - 1, 2, H, W) float64 pixels (x, y)."""
    gray = (luminance(torch.as_tensor(frames).double()).clamp(0, 1) * 255).round()
    gray = gray[:, 0].to(torch.uint8).cpu().numpy()
    flows = [cv2.calcOpticalFlowFarneback(a, b, None, *FARNEBACK) for a, b in zip(gray, gray[1:])]
    if not flows:
        return torch.zeros((0, 2, *gray.shape[1:]), dtype=torch.float64)
    return torch.from_numpy(np.stack(flows).astype(np.float64)).permute(0, 3, 1, 2)


def tof(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """tOF of consecutive frames of one clip (the module's docstring).

    Parameters
    ----------
    pred, target : (N, 3, H, W) float in [0, 1], frames 0 .. N-1 in order
    mask : (N, 1, H, W) or None; pair (t, t+1) uses the union (max) of the two frames' masks

    Returns
    -------
    (N - 1,) float64 pixels: ``mean |F_R - F_I|``; NaN for an empty mask; empty when N < 2
    """
    pred, target, mask = _check_images(pred, target, mask)
    return _pair_mean((optical_flow(pred) - optical_flow(target)).to(pred.device), mask)


def summarise(values) -> dict[str, float | int | None]:
    """``{"mean", "std", "n"}`` of the finite values (population std); None when n = 0."""
    a = np.asarray(values, np.float64).ravel()
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(a.mean()), "std": float(a.std()), "n": int(a.size)}


class FrameMetrics:
    """Collects per-frame metric values over batches (float64) and summarises them.

    ``update`` takes a batch of frames; with ``clip`` (any hashable id) the frames are the next
    consecutive frames of that clip, and the flicker of each consecutive pair is recorded, also
    across calls (the last frame of each clip is kept). Without ``clip`` no flicker is recorded.

    Example::

        fm = FrameMetrics()
        for batch in loader:
            fm.update(render(batch), batch["target"][:, 1], batch["target_mask"][:, 1])
        write_json(path, fm.summary())
    """

    def __init__(self, metrics: tuple[str, ...] = METRICS):
        unknown = set(metrics) - set(METRICS)
        if unknown:
            raise InputError(f"unknown metrics {sorted(unknown)}; choose from {list(METRICS)}")
        self.metrics = tuple(metrics)
        self.values: dict[str, list[float]] = {m: [] for m in self.metrics}
        self._last: dict[Hashable, tuple] = {}

    def add(self, name: str, values) -> None:
        """Append per-frame values of one metric (NaN = frame not counted)."""
        if name not in self.values:
            raise InputError(f"metric {name!r} is not collected here")
        self.values[name].extend(float(v) for v in torch.as_tensor(values).double().ravel())

    def update(
        self,
        pred: torch.Tensor,
        target: torch.Tensor,
        mask: torch.Tensor | None = None,
        *,
        clip: Hashable | None = None,
    ) -> None:
        """Add a batch: pred, target (N, 3, H, W) in [0, 1]; mask (N, 1, H, W) or None (the
        masked metrics are then skipped)."""
        pred, target, mask = _check_images(pred, target, mask)
        want = set(self.metrics)
        err = mse(pred, target)
        if "mse" in want:
            self.add("mse", err)
        if "psnr" in want:
            self.add("psnr", psnr_from_mse(err))
        if "ssim" in want:
            self.add("ssim", ssim(pred, target))
        if mask is not None:
            err_m = mse(pred, target, mask)
            if "mse_masked" in want:
                self.add("mse_masked", err_m)
            if "psnr_masked" in want:
                self.add("psnr_masked", psnr_from_mse(err_m))
            if "ssim_masked" in want:
                self.add("ssim_masked", ssim(pred, target, mask))
            if "gmsd_masked" in want:
                self.add("gmsd_masked", gmsd(pred, target, mask))
            if "gms_masked" in want:
                self.add("gms_masked", gms_deficit(pred, target, mask))
            if "detail_masked" in want:
                self.add("detail_masked", detail_ratio(pred, target, mask))
        if clip is None or not want & {"flicker", "flicker_masked", "tof_masked"}:
            return
        if clip in self._last:
            p0, t0, m0 = self._last[clip]
            if p0.shape[1:] != pred.shape[1:] or (m0 is None) != (mask is None):
                raise InputError(f"clip {clip!r} changed image size or mask use between calls")
            pred_s, target_s = torch.cat([p0, pred]), torch.cat([t0, target])
            mask_s = None if mask is None else torch.cat([m0, mask])
        else:
            pred_s, target_s, mask_s = pred, target, mask
        if "flicker" in want:
            self.add("flicker", flicker(pred_s, target_s))
        if mask_s is not None and "flicker_masked" in want:
            self.add("flicker_masked", flicker(pred_s, target_s, mask_s))
        if mask_s is not None and "tof_masked" in want:
            self.add("tof_masked", tof(pred_s, target_s, mask_s))
        self._last[clip] = (pred[-1:], target[-1:], None if mask is None else mask[-1:])

    def summary(self) -> dict[str, dict[str, float | int | None]]:
        """``{metric: {"mean", "std", "n"}}`` over the frames seen (JSON-ready: no NaN/inf)."""
        return {m: summarise(self.values[m]) for m in self.metrics}
