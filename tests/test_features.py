"""UV and motion-feature maps: against direct computations, at numeric extremes, numpy vs torch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from core.camera import make_camera, pixel_rays
from core.errors import InputError
from core.features import (
    FeatureConfig,
    interpolate,
    interpolate_reference,
    interpolate_torch,
    joint_window,
    motion_feature_map,
    uv_map,
    vertex_motion_features,
    vertex_motion_features_reference,
    vertex_motion_features_torch,
)
from core.raster import rasterize
from core.skeleton import CANONICAL_JOINTS
from tests.conftest import assert_close
from tests.test_raster import open_skirt


def grid_plane(n=6):
    """The square [-1, 1]^2 in the plane z = 0 as an n x n vertex grid, uv = ((x+1)/2, (y+1)/2)."""
    x, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1).astype(np.float32)
    uv = np.stack([(x.ravel() + 1) / 2, (y.ravel() + 1) / 2], 1).astype(np.float32)
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            f += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return v, np.array(f, np.int64), uv


def test_uv_map_matches_the_analytic_plane():
    v, f, uv = grid_plane()
    cam = make_camera((0.4, 0.3, 2.5), (0.1, 0.0, 0.0), width=60, height=50, fov_y_deg=40)
    fr = rasterize(v, f, cam)
    m = uv_map(fr, f, uv)
    assert m.shape == (50, 60, 2) and m.dtype == np.float32
    assert fr.mask.sum() > 500
    assert (m[~fr.mask] == 0).all()
    # Intersect each pixel-centre ray with z = 0: uv is linear in the hit point.
    origin, d = pixel_rays(cam)
    t = -origin[2] / d[:, 2]
    hit = (origin + d * t[:, None]).reshape(50, 60, 3)
    expected = (hit[..., :2] + 1) / 2
    assert_close(m[fr.mask], expected[fr.mask], atol=1e-5, what="uv map vs ray-plane hit")


def test_interpolation_matches_reference_per_vertex_and_per_corner(rng):
    v, f = open_skirt()
    cam = make_camera((0.3, 1.6, 1.5), (0, 0.9, 0), width=40, height=32)
    fr = rasterize(v, f, cam)
    attrs = rng.normal(size=(len(v), 5)).astype(np.float32)
    ref = interpolate_reference(fr, f, attrs)
    assert_close(interpolate(fr, f, attrs), ref, atol=1e-5, what="per-vertex")
    corners = rng.normal(size=(len(f), 3, 4)).astype(np.float32)  # seams: corners disagree
    assert_close(interpolate(fr, f, corners), interpolate_reference(fr, f, corners), atol=1e-5)
    # Per-corner copies of per-vertex values give the same map.
    assert_close(interpolate(fr, f, attrs[f]), ref, atol=1e-5, what="corners from vertices")
    half = interpolate(fr, f, attrs, "float16")
    assert half.dtype == np.float16
    assert_close(half, ref, atol=5e-3, rtol=2e-3, what="float16 output")


def test_interpolation_in_many_blocks(rng, monkeypatch):
    from core import features

    v, f, _ = grid_plane(9)
    cam = make_camera((0.0, 0.0, 2.2), (0, 0, 0), width=70, height=64, fov_y_deg=60)
    fr = rasterize(v, f, cam)
    assert fr.mask.sum() > features._BLOCK  # several blocks with the default size
    attrs = rng.normal(size=(len(v), 95)).astype(np.float32)
    corners = rng.normal(size=(len(f), 3, 12)).astype(np.float32)  # > _FEW_CHANNELS: blocks
    direct = np.einsum("hwk,hwkc->hwc", fr.barycentrics, attrs[f[np.maximum(fr.face_id, 0)]])
    direct[~fr.mask] = 0
    assert_close(interpolate(fr, f, attrs), direct, atol=1e-5, what="default blocks")
    ref_corners = interpolate(fr, f, corners)
    monkeypatch.setattr(features, "_BLOCK", 7)  # ragged last block
    assert_close(interpolate(fr, f, attrs), direct, atol=1e-5, what="blocks of 7")
    assert_close(interpolate(fr, f, corners), ref_corners, atol=1e-6, what="corners, blocks of 7")
    idx = np.flatnonzero(fr.mask.ravel())[::97]  # spot-check per-corner against the loop
    sub = interpolate_reference(fr, f, corners).reshape(-1, 12)[idx]
    assert_close(ref_corners.reshape(-1, 12)[idx], sub, atol=1e-5, what="corners vs reference")
    # Few channels take the unblocked path: same values.
    assert_close(interpolate(fr, f, corners[..., :2]), ref_corners[..., :2], atol=1e-6)


def test_interpolation_rejects_bad_shapes():
    v, f = open_skirt()
    fr = rasterize(v, f, make_camera((0, 1, 2), (0, 1, 0), width=8, height=8))
    with pytest.raises(InputError):
        interpolate(fr, f, np.zeros((3, 2)))  # too few vertices
    with pytest.raises(InputError):
        interpolate(fr, f, np.zeros((len(f), 2, 2)))  # corners must be 3
    with pytest.raises(InputError):
        uv_map(fr, f, np.zeros((len(v), 3)))


def test_joint_window_offsets_and_clamping():
    joints = np.arange(10)[:, None, None] * np.ones((10, 19, 3))
    w = joint_window(joints, 5)
    assert w.shape == (5, 19, 3) and w.dtype == np.float32
    assert w[:, 0, 0].tolist() == [5, 3, 1, 0, 0]  # t, t-2, t-4, then frame 0 repeated
    assert joint_window(joints, 9, (0, 1))[:, 0, 0].tolist() == [9, 8]
    with pytest.raises(InputError):
        joint_window(joints, 10)


def test_vertex_features_match_reference_and_channel_order(rng):
    v = rng.uniform(-0.5, 0.5, (30, 3)) + [0, 1, 0]
    window = rng.uniform(-0.5, 0.5, (5, 19, 3)) + [0, 1, 0]
    fast = vertex_motion_features(v, window, 0.1)
    ref = vertex_motion_features_reference(v, window, 0.1)
    assert fast.shape == (30, 95) and fast.dtype == np.float32
    assert_close(fast, ref, atol=1e-6, what="motion features")
    # Channel k * 19 + j is joint j at frame offset k, against the current vertex.
    k, j = 3, CANONICAL_JOINTS.index("LeftUpLeg")
    d2 = ((v - window[k, j]) ** 2).sum(1)
    assert_close(fast[:, k * 19 + j], np.exp(-d2 / 0.1), atol=1e-6, what="channel order")


def test_motion_feature_map_interpolates_vertex_features():
    v, f = open_skirt()
    joints = np.random.default_rng(1).uniform(-0.3, 0.3, (12, 19, 3)) + [0, 1, 0]
    window = joint_window(joints, 11)
    cam = make_camera((0.2, 1.1, 1.8), (0, 0.9, 0), width=24, height=20)
    fr = rasterize(v, f, cam)
    m = motion_feature_map(fr, f, v, window)
    assert m.shape == (20, 24, 95) and m.dtype == np.float32
    assert (m[~fr.mask] == 0).all()
    assert ((m >= 0) & (m <= 1)).all()
    ref = interpolate_reference(fr, f, vertex_motion_features_reference(v, window, 0.1))
    assert_close(m, ref, atol=1e-5, what="feature map")
    half = motion_feature_map(fr, f, v, window, FeatureConfig(dtype="float16"))
    assert half.dtype == np.float16
    assert_close(half, ref, atol=2e-3, what="float16 feature map")
    with pytest.raises(InputError):
        motion_feature_map(fr, f, v, window[:3])  # config expects 5 frames


@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_extremes_are_finite_and_exact(dtype):
    v = np.array([[0.0, 1.0, 0.0], [0.3, 1.0, 0.0], [1e19, -1e19, 3e38]], np.float32)
    window = np.zeros((2, 3, 3), np.float32)
    window[:, 0] = [0.0, 1.0, 0.0]  # coincides with vertex 0
    window[:, 1] = [0.0, 1.0, 0.3]
    window[:, 2] = [-3e38, 3e38, -3e38]  # as far as float32 goes
    for sigma in (1e-45, 1e-30, 1e-6, 0.1, 1e6, 1e30, 1e300):
        out = vertex_motion_features(v, window, sigma, dtype)
        assert out.dtype == np.dtype(dtype)
        assert np.isfinite(out).all() and ((out >= 0) & (out <= 1)).all(), f"sigma {sigma}"
        assert out[0, 0] == 1.0  # distance 0: exp(0) whatever sigma
        if sigma <= 1e30:
            assert (out[:2, 2] == 0).all() and (out[2, :2] == 0).all()  # far joints: exactly 0
        else:
            assert (out == 1).all()  # (6.8e38 m)^2 / 1e300 m^2 is still ~0: exp gives 1
        if sigma <= 1e-6:
            assert out[0, 1] == 0 and out[1, 0] == 0  # tiny sigma: anything apart is 0
        if sigma >= 1e6:
            assert out[0, 1] == pytest.approx(1.0, abs=1e-3)  # huge sigma: near joints give 1
    # float16 inputs are widened before squaring (0.3^2 / 1e-4 overflows float16, not float32).
    out = vertex_motion_features(v[:2].astype(np.float16), window[:, :2].astype(np.float16), 1e-4)
    assert np.isfinite(out).all() and out[0, 0] == 1.0 and out[0, 1] == 0.0


@pytest.mark.parametrize("sigma", [1e-30, 1e-6, 0.1, 1e6, 1e30])
def test_float32_regime_limits_match_reference(sigma):
    """The float32 fast path's edges (coordinates < 1e15 m, sigma in [1e-30, 1e30])."""
    v = np.array([[0.0, 1.0, 0.0], [0.3, 1.0, 0.0], [9e14, 0.0, -9e14]], np.float32)
    window = np.array([[[0.0, 1.0, 0.0], [0.0, 1.0, 0.3], [-9e14, 9e14, 9e14]]], np.float32)
    for dtype in ("float32", "float16"):
        out = vertex_motion_features(v, window, sigma, dtype)
        assert np.isfinite(out).all() and ((out >= 0) & (out <= 1)).all()
        ref = vertex_motion_features_reference(v, window, sigma)
        assert_close(out, ref, atol=1e-6 if dtype == "float32" else 1e-3, what=dtype)


@pytest.mark.parametrize("sigma", [0.0, -0.1, float("nan"), float("inf")])
def test_bad_sigma_raises(sigma):
    with pytest.raises(InputError):
        FeatureConfig(sigma=sigma)
    with pytest.raises(InputError):
        vertex_motion_features(np.zeros((1, 3)), np.zeros((1, 1, 3)), sigma)


def test_non_finite_inputs_raise():
    window = np.zeros((5, 19, 3))
    with pytest.raises(InputError):
        vertex_motion_features(np.array([[np.nan, 0, 0]]), window)
    window[2, 4, 1] = np.inf
    with pytest.raises(InputError):
        vertex_motion_features(np.zeros((2, 3)), window)


def test_torch_versions_match_numpy(rng):
    v, f = open_skirt()
    window = (rng.uniform(-0.3, 0.3, (5, 19, 3)) + [0, 1, 0]).astype(np.float32)
    feats = vertex_motion_features(v, window, 0.1)
    tv, tw = torch.from_numpy(v), torch.from_numpy(window)
    t_feats = vertex_motion_features_torch(tv, tw, 0.1)
    assert_close(t_feats.numpy(), feats, atol=1e-6, what="torch vertex features")
    # Batched, and half precision at the extremes.
    batch = vertex_motion_features_torch(tv[None].repeat(2, 1, 1), tw[None].repeat(2, 1, 1, 1), 0.1)
    assert batch.shape == (2, len(v), 95)
    assert_close(batch[1].numpy(), feats, atol=1e-6)
    for sigma in (1e-45, 1e30):
        half = vertex_motion_features_torch(tv.half(), tw.half(), sigma)
        assert half.dtype == torch.float16 and torch.isfinite(half).all()
        assert_close(
            half.float().numpy(), vertex_motion_features(v, window, sigma, "float16"), atol=1e-3
        )
    cam = make_camera((0.3, 1.4, 1.6), (0, 0.9, 0), width=30, height=26)
    fr = rasterize(v, f, cam)
    ref = interpolate(fr, f, feats)
    got = interpolate_torch(
        torch.from_numpy(fr.face_id),
        torch.from_numpy(fr.barycentrics),
        torch.from_numpy(f),
        t_feats,
    )
    assert got.shape == ref.shape
    assert_close(got.numpy(), ref, atol=1e-5, what="torch interpolation")
    # Batched attributes (B, V, C) with face ids (B, H, W).
    fid = torch.from_numpy(fr.face_id)[None].repeat(2, 1, 1)
    bar = torch.from_numpy(fr.barycentrics)[None].repeat(2, 1, 1, 1)
    got_b = interpolate_torch(fid, bar, torch.from_numpy(f), batch)
    assert_close(got_b[1].numpy(), ref, atol=1e-5, what="batched torch interpolation")
    assert (got_b[:, ~torch.from_numpy(fr.mask)] == 0).all()
