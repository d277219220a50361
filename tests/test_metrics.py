"""Evaluation metrics (MSE, PSNR, SSIM, flicker, accumulator) and FID with a small Inception."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from torch.nn import functional as F

from core.errors import InputError
from tests.conftest import assert_close
from training import inception
from training.metrics import (
    GMSD_C,
    LUMA,
    PSNR_CAP_DB,
    FrameMetrics,
    detail_ratio,
    flicker,
    gms_deficit,
    gmsd,
    gradient_magnitude,
    gradient_similarity,
    luminance,
    mse,
    psnr,
    ssim,
    ssim_reference,
    tof,
)

torch.set_num_threads(1)


def _images(n=2, size=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 3, size, size, generator=g)


# -- MSE / PSNR ------------------------------------------------------------------------------


def test_mse_and_psnr_of_constant_offsets():
    a = torch.full((2, 3, 12, 12), 0.5)
    b = a.clone()
    b[0] += 0.1
    b[1] -= 0.2
    assert_close(mse(a, b), [0.01, 0.04], atol=1e-7)  # float32 inputs
    assert_close(psnr(a, b), [20.0, 10 * math.log10(1 / 0.04)], atol=1e-5)


def test_psnr_of_identical_images_is_the_cap():
    a = _images()
    assert_close(psnr(a, a), [PSNR_CAP_DB, PSNR_CAP_DB])


def test_masked_mse_counts_only_the_mask_and_empty_is_nan():
    a = torch.zeros(2, 3, 12, 12)
    b = a.clone()
    b[:, :, :6] = 1.0  # top half wrong
    mask = torch.zeros(2, 1, 12, 12)
    mask[0, :, 6:] = 1  # frame 0: bottom half only (all correct)
    mask[0, :, 5] = 1  # plus one wrong row
    got = mse(a, b, mask)
    assert got[0].item() == pytest.approx(1 / 7)
    assert math.isnan(got[1].item())


def test_bad_shapes_raise():
    with pytest.raises(InputError):
        mse(torch.zeros(2, 3, 8, 8), torch.zeros(2, 3, 8, 9))
    with pytest.raises(InputError):
        mse(torch.zeros(2, 1, 8, 8), torch.zeros(2, 1, 8, 8))
    with pytest.raises(InputError):
        mse(torch.zeros(2, 3, 8, 8), torch.zeros(2, 3, 8, 8), torch.zeros(2, 3, 8, 8))
    with pytest.raises(InputError, match="11 px"):
        ssim(torch.zeros(1, 3, 8, 8), torch.zeros(1, 3, 8, 8))


# -- SSIM ------------------------------------------------------------------------------------


def test_ssim_of_identical_and_constant_images_is_one():
    a = _images()
    assert_close(ssim(a, a), [1.0, 1.0], atol=1e-12)
    c = torch.full((1, 3, 16, 16), 0.3)
    assert_close(ssim(c, c), [1.0], atol=1e-12)


def test_ssim_decreases_with_noise():
    a = _images(1, 24)
    g = torch.Generator().manual_seed(1)
    noise = torch.randn(a.shape, generator=g)
    values = [ssim(a, (a + s * noise).clamp(0, 1)).item() for s in (0.0, 0.02, 0.1, 0.3)]
    assert values[0] == pytest.approx(1.0)
    assert all(x > y for x, y in zip(values, values[1:])), values


def test_ssim_matches_the_slow_reference():
    a, b = _images(2, 14, seed=2), _images(2, 14, seed=3)
    b = 0.5 * a + 0.5 * b
    assert_close(ssim(a, b), ssim_reference(a.numpy(), b.numpy()), atol=1e-10, what="SSIM")


def test_ssim_matches_pytorch_msssim():
    """A maintained library (pytorch-msssim) gives the same full-frame SSIM: same window, same
    constants, "valid" filtering, channels averaged. Ours stays because the garment-region SSIM
    needs the map of window SSIMs, which the library does not return."""
    from pytorch_msssim import ssim as library_ssim

    a = _images(3, 64, seed=7).double()
    b = (0.6 * a + 0.4 * _images(3, 64, seed=8).double()).clamp(0, 1)
    b[1] = a[1]  # identical frames: 1 in both
    theirs = library_ssim(a, b, data_range=1.0, size_average=False)
    assert_close(ssim(a, b), theirs, atol=1e-6, what="SSIM against pytorch-msssim")


def test_masked_ssim_averages_inside_the_mask():
    a = _images(1, 24)
    b = a.clone()
    b[:, :, 12:] = _images(1, 24, seed=5)[:, :, 12:]  # bottom half differs
    top = torch.zeros(1, 1, 24, 24)
    top[:, :, :6] = 1  # window centres 5..5 rows from the top: far from the changed half
    assert ssim(a, b, top).item() == pytest.approx(1.0)
    assert ssim(a, b).item() < 0.95
    empty = torch.zeros(1, 1, 24, 24)
    empty[:, :, :3] = 1  # only in the 5 px border: no window centre inside
    assert math.isnan(ssim(a, b, empty).item())


# -- flicker and the accumulator ------------------------------------------------------------


def test_flicker_is_zero_for_a_consistent_offset_and_sees_jitter():
    gt = _images(4, 12)
    assert_close(flicker(gt + 0.1, gt), np.zeros(3), atol=1e-7)  # float32 rounding
    jitter = gt.clone()
    jitter[1] += 0.2
    got = flicker(jitter, gt)
    assert_close(got, [0.2, 0.2, 0.0], atol=1e-7)
    assert flicker(gt[:1], gt[:1]).numel() == 0


def _moving_pattern(frames: int, step: int, size: int = 64) -> torch.Tensor:
    """A smooth random texture (grey, 3 channels) moving ``step`` px right each frame:
    (frames, 3, size, size) in [0, 1]."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(4)
    base = gaussian_filter(rng.random((size, size + step * frames)), 1.5)
    base = (base - base.min()) / (base.max() - base.min())
    shots = [base[:, step * (frames - k) : step * (frames - k) + size] for k in range(frames)]
    return torch.from_numpy(np.stack(shots)).float()[:, None].repeat(1, 3, 1, 1)


def test_tof_known_answers():
    """Identical videos: 0. A rendering that stands still while the ground truth moves 2 px a
    frame to the right: the flow differs by 2 px in x and 0 in y, a mean of 1 over the two
    components. A rendering that moves as the ground truth does, darker: about 0 (tOF is about
    motion, not colour). An empty mask: NaN; one frame: no pair."""
    truth = _moving_pattern(3, 2)
    inner = torch.zeros(3, 1, 64, 64)
    inner[:, :, 16:48, 16:48] = 1.0  # away from the borders, where the flow is guessed
    assert_close(tof(truth, truth, inner), [0.0, 0.0], atol=1e-12)
    still = truth[:1].repeat(3, 1, 1, 1)
    assert_close(tof(still, truth, inner), [1.0, 1.0], atol=0.1)
    assert tof(0.7 * truth, truth, inner).max() < 0.1
    assert torch.isnan(tof(still, truth, torch.zeros(3, 1, 64, 64))).all()
    assert tof(truth[:1], truth[:1]).numel() == 0


def test_frame_metrics_summary_across_batches_and_clips():
    gt = _images(5, 12)
    pred = gt.clone()
    pred[2] += 0.1
    mask = torch.ones(5, 1, 12, 12)
    mask[4] = 0  # one frame with an empty mask
    fm = FrameMetrics()
    fm.update(pred[:2], gt[:2], mask[:2], clip="a")
    fm.update(pred[2:], gt[2:], mask[2:], clip="a")  # continues the clip across the call
    s = fm.summary()
    assert s["mse"]["n"] == 5
    assert s["mse"]["mean"] == pytest.approx(0.01 / 5)
    assert s["mse_masked"]["n"] == 4
    assert s["flicker"]["n"] == 4
    assert s["flicker"]["mean"] == pytest.approx((0.1 + 0.1) / 4)
    assert s["tof_masked"]["n"] == 4  # a pair per step of the clip, the empty mask's included
    assert s["psnr"]["mean"] == pytest.approx((4 * PSNR_CAP_DB + 20.0) / 5)
    json.dumps(s, allow_nan=False)  # valid JSON: no NaN or inf anywhere


def test_frame_metrics_with_nothing_counted_reports_n_zero():
    fm = FrameMetrics()
    gt = _images(2, 12)
    fm.update(gt, gt, torch.zeros(2, 1, 12, 12))
    s = fm.summary()
    assert s["mse_masked"] == {"mean": None, "std": None, "n": 0}
    assert s["flicker"]["n"] == 0
    json.dumps(s, allow_nan=False)


# -- FID -------------------------------------------------------------------------------------

SCALE = 1 / 16
CFG = inception.InceptionConfig(width_scale=SCALE, image_size=75, batch_size=8)


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    torch.manual_seed(0)
    net = inception.InceptionV3(width_scale=SCALE)
    for m in net.modules():  # calibrate batch norm so features are not vanishingly small
        if isinstance(m, torch.nn.BatchNorm2d):
            m.momentum = None
    with torch.no_grad():
        net.train().features(torch.rand(16, 3, 75, 75) * 2 - 1)
    path = tmp_path_factory.mktemp("inc") / "inception_small.pth"
    torch.save(net.state_dict(), path)
    return path


def test_inception_layout_matches_torchvision_names():
    keys = inception.InceptionV3(width_scale=SCALE).state_dict().keys()
    for k in (
        "Conv2d_1a_3x3.conv.weight",
        "Conv2d_1a_3x3.bn.running_mean",
        "Mixed_5b.branch1x1.conv.weight",
        "Mixed_6b.branch7x7dbl_5.bn.weight",
        "Mixed_7c.branch3x3_2b.conv.weight",
        "fc.weight",
    ):
        assert k in keys
    full = inception.InceptionV3(width_scale=1.0)
    assert full.feature_dim == 2048
    assert tuple(full.state_dict()["Mixed_7c.branch_pool.conv.weight"].shape) == (192, 2048, 1, 1)
    assert tuple(full.state_dict()["Mixed_6e.branch7x7_1.conv.weight"].shape) == (192, 768, 1, 1)


def test_small_inception_round_trip(weights):
    net = inception.load_inception(weights, width_scale=SCALE)
    ref = inception.InceptionV3(width_scale=SCALE)
    ref.load_state_dict(torch.load(weights, weights_only=True))
    ref.eval()
    x = _images(2, 40)
    assert_close(
        inception.extract_features(net, x, CFG), inception.extract_features(ref, x, CFG), 1e-6
    )
    assert inception.extract_features(net, x, CFG).shape == (2, net.feature_dim)


def test_fid_identical_sets_is_zero_and_grows_with_shift(weights):
    real = _images(24, 32, seed=7)
    same = inception.fid(real, real, weights, CFG)
    assert same.value == pytest.approx(0.0, abs=1e-4)
    shifted = [
        inception.fid(real, (real * (1 - s) + s).clamp(0, 1), weights, CFG) for s in (0.2, 0.6)
    ]
    assert 0 < shifted[0].value < shifted[1].value
    json.dumps(shifted[0].to_dict(), allow_nan=False)


def test_video_fid(weights):
    clip = _images(8, 32, seed=8)
    assert inception.video_fid([clip], [clip], weights, CFG).value == pytest.approx(0, abs=1e-4)
    jitter = clip + 0.2 * (torch.arange(8) % 2).view(-1, 1, 1, 1)
    assert inception.video_fid([clip], [jitter.clamp(0, 1)], weights, CFG).value > 0


def test_fid_without_weights_is_unavailable_not_a_number():
    real = _images(4, 32)
    r = inception.fid(real, real, None)
    assert r.value is None
    assert r.status.startswith("unavailable: no Inception weights file given")
    assert inception.video_fid([real], [real], "").value is None


def test_bad_weight_files(tmp_path, weights):
    with pytest.raises(InputError, match="not found") as e:
        inception.load_inception(tmp_path / "missing.pth", width_scale=SCALE)
    assert "missing.pth" in str(e.value)
    bad = tmp_path / "corrupt.pth"
    bad.write_bytes(b"not a torch file")
    with pytest.raises(InputError, match="corrupt.pth"):
        inception.load_inception(bad, width_scale=SCALE)
    wrong = tmp_path / "wrong.pth"
    torch.save({"features.0.weight": torch.zeros(3)}, wrong)
    with pytest.raises(InputError, match="wrong.pth"):
        inception.load_inception(wrong, width_scale=SCALE)
    with pytest.raises(InputError, match="shape"):
        inception.load_inception(weights, width_scale=1 / 8)


def test_frechet_distance_of_known_gaussians():
    mu1, mu2 = np.zeros(3), np.array([1.0, 2.0, 2.0])
    s = np.diag([1.0, 2.0, 3.0])
    assert inception.frechet_distance(mu1, s, mu2, s) == pytest.approx(9.0)
    # 1-D: (m1 - m2)^2 + s1 + s2 - 2 sqrt(s1 s2)
    d = inception.frechet_distance(np.zeros(1), np.eye(1) * 4, np.zeros(1), np.eye(1))
    assert d == pytest.approx(1.0)
    sing = np.zeros((3, 3))  # singular covariances take the eps offset path
    assert inception.frechet_distance(mu1, sing, mu1, sing) == pytest.approx(0.0, abs=1e-6)


def _textured(n=2, size=48, seed=0) -> torch.Tensor:
    """Images with detail at the finest scale (uniform noise), in [0, 1]."""
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 3, size, size, generator=g, dtype=torch.float64)


def _box_blur(x: torch.Tensor) -> torch.Tensor:
    return F.avg_pool2d(F.pad(x, (1, 1, 1, 1), mode="replicate"), 3, 1)


def test_gmsd_and_detail_ratio_know_identical_blurred_and_shifted_images():
    x = _textured()
    mask = torch.ones(2, 1, 48, 48, dtype=torch.float64)
    assert torch.equal(gmsd(x, x, mask), torch.zeros(2, dtype=torch.float64))
    assert torch.allclose(detail_ratio(x, x, mask), torch.ones(2, dtype=torch.float64))
    blurred, shifted = _box_blur(x), torch.roll(x, 1, dims=3)
    # blur removes fine detail: far below 1; a shift moves it: as much detail, but GMSD sees it
    assert (detail_ratio(blurred, x, mask) < 0.3).all()
    ones = torch.ones(2, dtype=torch.float64)
    assert torch.allclose(detail_ratio(shifted, x, mask), ones, atol=0.02)
    assert (gmsd(blurred, x, mask) > 0.1).all() and (gmsd(shifted, x, mask) > 0.1).all()
    # more blur, worse GMSD; noise added: detail above 1
    assert (gmsd(_box_blur(blurred), x, mask) > gmsd(blurred, x, mask)).all()
    g = torch.Generator().manual_seed(1)
    noisy = (x + 0.2 * torch.randn(x.shape, generator=g, dtype=torch.float64)).clamp(0, 1)
    assert (detail_ratio(noisy, x, mask) > 1.1).all()


def test_gmsd_matches_an_obvious_loop_and_counts_only_the_mask():
    x, y = _textured(1, 12, 2), _textured(1, 12, 3)
    a, b = (sum(w * im[0, c].numpy() for c, w in enumerate(LUMA)) for im in (y, x))

    def mag(im, i, j):  # Prewitt, divided by 3, at pixel (i, j)
        gx = (im[i - 1 : i + 2, j - 1] - im[i - 1 : i + 2, j + 1]).sum() / 3
        gy = (im[i - 1, j - 1 : j + 2] - im[i + 1, j - 1 : j + 2]).sum() / 3
        return np.hypot(gx, gy)

    sims = []
    for i in range(1, 11):
        for j in range(1, 11):
            p, t = mag(a, i, j), mag(b, i, j)
            sims.append((2 * p * t + GMSD_C) / (p * p + t * t + GMSD_C))
    assert gmsd(y, x).item() == pytest.approx(np.std(sims), abs=1e-12)
    # outside the mask anything goes; an empty mask is NaN
    mask = torch.zeros(1, 1, 12, 12, dtype=torch.float64)
    mask[..., :6, :] = 1
    damaged = y.clone()
    damaged[..., 8:, :] = 0
    assert gmsd(damaged, x, mask).item() == pytest.approx(gmsd(y, x, mask).item())
    assert torch.isnan(gmsd(y, x, torch.zeros_like(mask))).all()


def test_gms_deficit_is_the_mean_of_the_map_gmsd_the_spread_and_blur_lowers_only_gmsd():
    """Stripes, and a render of them with the lower half a pixel off. Blurring that render
    misses every edge alike: GMSD (the map's spread) falls, though the render is further from
    the truth; the mean deficit rises. Identical images: 0 both; the mask counts as GMSD's."""
    x = torch.zeros(1, 3, 48, 48, dtype=torch.float64)
    for c in range(0, 48, 6):
        x[..., c : c + 3] = 1.0
    half = x.clone()
    half[..., 24:, :] = torch.roll(x, 1, dims=3)[..., 24:, :]
    mask = torch.ones(1, 1, 48, 48, dtype=torch.float64)
    assert gms_deficit(x, x, mask).item() == 0.0
    once, twice = _box_blur(half), _box_blur(_box_blur(half))
    assert gmsd(twice, x, mask) < gmsd(once, x, mask) < gmsd(half, x, mask)
    assert gms_deficit(half, x, mask) < gms_deficit(once, x, mask) < gms_deficit(twice, x, mask)
    # the same map as GMSD's: its mean over the mask's inner pixels, NaN for an empty mask
    y, z = _textured(1, 12, 2), _textured(1, 12, 3)
    m = torch.zeros(1, 1, 12, 12, dtype=torch.float64)
    m[..., :6, :] = 1
    gms = gradient_similarity(gradient_magnitude(luminance(y)), gradient_magnitude(luminance(z)))
    assert gms_deficit(y, z, m).item() == pytest.approx(1 - gms[..., :5, :].mean().item())
    assert torch.isnan(gms_deficit(y, z, torch.zeros_like(m))).all()


def test_detail_ratio_of_a_flat_ground_truth_is_nan():
    flat = torch.full((1, 3, 8, 8), 0.5, dtype=torch.float64)
    assert torch.isnan(detail_ratio(_textured(1, 8), flat)).all()
