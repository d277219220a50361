"""Cameras: OpenCV conventions, Open3D's ray convention, resize/crop, rigs, JSON files."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from core.camera import (
    Camera,
    CameraRigConfig,
    camera_from_dict,
    camera_to_dict,
    crop_camera,
    dolly_view,
    intrinsics_from_fov,
    load_cameras,
    look_at,
    make_camera,
    orbit_path,
    orbit_view,
    pan_view,
    pixel_rays,
    project,
    random_cameras,
    resize_camera,
    save_cameras,
    spherical_path,
    unproject,
)
from core.errors import InputError
from tests.conftest import assert_close


def test_look_at_axes_follow_opencv():
    cam = make_camera((0.0, 1.0, 5.0), (0.0, 1.0, 0.0), width=64, height=48)
    assert_close(cam.center, [0, 1, 5], atol=1e-12, what="center")
    assert_close(cam.forward, [0, 0, -1], atol=1e-12, what="forward")
    R = cam.R
    assert_close(R @ R.T, np.eye(3), atol=1e-12, what="R R^T")
    assert np.linalg.det(R) == pytest.approx(1.0)
    uv, depth = project(np.array([[0, 1, 0], [1, 1, 0], [0, 2, 0], [0, 1, 10]]), cam)
    assert_close(uv[0], [32, 24], atol=1e-9, what="target at the principal point")
    assert depth[0] == pytest.approx(5.0)
    assert uv[1, 0] > 32  # world +X is to the right for a camera on +Z looking at -Z
    assert uv[2, 1] < 24  # world up is image up: y decreases
    assert depth[3] < 0 and np.isnan(uv[3]).all()  # behind the camera


def test_look_at_rejects_degenerate_views():
    with pytest.raises(InputError):
        look_at((0, 0, 0), (0, 0, 0))
    with pytest.raises(InputError):
        look_at((0, 5, 0), (0, 0, 0))  # looking straight down along -up


def test_fov_round_trip_and_bad_values():
    K = intrinsics_from_fov(50.0, 320, 240)
    cam = Camera(K, np.eye(4), 320, 240)
    assert cam.fov_y_deg == pytest.approx(50.0)
    assert (cam.cx, cam.cy) == (160.0, 120.0)
    for bad in (0.0, 180.0, -5.0):
        with pytest.raises(InputError):
            intrinsics_from_fov(bad, 320, 240)


def test_pixel_rays_match_open3d_create_rays_pinhole():
    import open3d as o3d

    cam = make_camera((0.7, 1.3, 2.1), (0.1, 0.9, -0.2), width=37, height=23, fov_y_deg=55)
    cam = crop_camera(cam, 3, -2, 37, 23)  # off-centre principal point too
    rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
        o3d.core.Tensor(cam.K), o3d.core.Tensor(cam.extrinsic), cam.width, cam.height
    ).numpy()
    origin, d = pixel_rays(cam)
    assert_close(rays[..., :3].reshape(-1, 3), np.broadcast_to(origin, d.shape), atol=1e-6)
    assert_close(rays[..., 3:].reshape(-1, 3), d, atol=1e-6, what="directions")


def test_project_unproject_round_trip(rng):
    cam = make_camera((1.0, 1.5, 3.0), (0, 0.8, 0), width=200, height=100)
    pts = rng.uniform(-1, 1, (50, 3)) + [0, 1, 0]
    uv, z = project(pts, cam)
    assert (z > 0).all()
    assert_close(unproject(uv, z, cam), pts, atol=1e-9, what="unproject(project(p))")
    # A ray through the projection of a point passes through the point.
    origin, d = pixel_rays(cam, uv)
    assert_close(origin + d * z[:, None], pts, atol=1e-9, what="ray at depth")


def test_resize_and_crop_are_exact(rng):
    cam = make_camera((0.3, 1.2, 2.5), (0, 1, 0), width=64, height=48)
    pts = rng.uniform(-0.5, 0.5, (20, 3)) + [0, 1, 0]
    uv, _ = project(pts, cam)
    big = resize_camera(cam, 192, 96)
    uv_big, _ = project(pts, big)
    assert_close(uv_big, uv * [3.0, 2.0], atol=1e-9, what="resized projection")
    crop = crop_camera(cam, 10, 5, 20, 30)
    uv_crop, _ = project(pts, crop)
    assert_close(uv_crop, uv - [10, 5], atol=1e-9, what="cropped projection")
    # Supersampling: the k x k sub-pixel centres of pixel (i, j) average to its centre.
    k = 3
    sub = resize_camera(cam, k * cam.width, k * cam.height)
    _, d_sub = pixel_rays(sub)
    _, d = pixel_rays(cam)
    mean = d_sub.reshape(cam.height, k, cam.width, k, 3).mean(axis=(1, 3)).reshape(-1, 3)
    assert_close(mean, d, atol=1e-12, what="mean sub-pixel ray")


def test_random_cameras_are_seeded_and_inside_the_rig():
    cfg = CameraRigConfig(width=64, height=64, target_jitter=0.0)
    a = random_cameras(10, 7, cfg)
    b = random_cameras(10, 7, cfg)
    c = random_cameras(10, (7, 1), cfg)
    assert len(a) == 10 and a == b and a != c
    target = np.array(cfg.target)
    for cam in a:
        uv, _ = project(target[None], cam)
        assert_close(uv[0], [32, 32], atol=1e-9, what="target at the image centre")
        off = cam.center - target
        radius = math.hypot(off[0], off[2])
        elevation = math.degrees(math.atan2(off[1], radius))
        assert cfg.radius_range[0] - 1e-9 <= radius <= cfg.radius_range[1] + 1e-9
        assert cfg.elevation_deg_range[0] - 1e-9 <= elevation <= cfg.elevation_deg_range[1] + 1e-9
    azimuths = [math.atan2(c.center[0], c.center[2]) for c in a]
    assert np.ptp(azimuths) > math.pi / 2  # spread around the body, not bunched


def test_rig_config_rejects_bad_ranges():
    with pytest.raises(InputError):
        CameraRigConfig(radius_range=(3.0, 2.0))
    with pytest.raises(InputError):
        CameraRigConfig(elevation_deg_range=(0.0, 95.0))
    with pytest.raises(InputError):
        CameraRigConfig(width=0)


def test_orbit_path_is_evenly_spaced():
    cfg = CameraRigConfig(width=32, height=32)
    cams = orbit_path(8, cfg, radius=2.0, elevation_deg=10.0)
    target = np.array(cfg.target)
    az = np.unwrap([math.atan2(c.center[0] - target[0], c.center[2] - target[2]) for c in cams])
    assert_close(np.diff(az), np.full(7, math.pi / 4), atol=1e-9, what="azimuth steps")
    for c in cams:
        assert np.linalg.norm(c.center - target) == pytest.approx(2.0)
    assert orbit_path(0, cfg) == []


def test_json_round_trip_is_exact(tmp_path):
    cams = random_cameras(4, 3, CameraRigConfig(width=96, height=80))
    cams.append(crop_camera(resize_camera(cams[0], 300, 200), 17, 9, 64, 32))
    path = tmp_path / "sub" / "cams.json"
    save_cameras(path, cams)
    assert load_cameras(path) == cams
    assert sorted(p.name for p in path.parent.iterdir()) == ["cams.json"]  # no temp files
    assert camera_from_dict(camera_to_dict(cams[1])) == cams[1]


@pytest.mark.parametrize(
    "text",
    [
        "{not json",
        "[]",
        '{"format": "other", "version": 1, "cameras": []}',
        '{"format": "garment-studio/cameras", "version": 99, "cameras": []}',
        '{"format": "garment-studio/cameras", "version": 1, "cameras": {}}',
        '{"format": "garment-studio/cameras", "version": 1, "cameras": [{"width": 4}]}',
        '{"format": "garment-studio/cameras", "version": 1, "cameras": [5]}',
    ],
)
def test_malformed_camera_files_raise_input_error(tmp_path, text):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        load_cameras(path)
    assert str(path) in str(info.value)


def _camera_dict(**changes):
    d = camera_to_dict(make_camera((0, 1, 3), (0, 1, 0), width=16, height=16))
    d.update(changes)
    return d


@pytest.mark.parametrize(
    "changes",
    [
        {"width": 0},
        {"width": 16.0},
        {"height": "16"},
        {"K": [[1, 0], [0, 1]]},
        {"K": [[-5, 0, 8], [0, 5, 8], [0, 0, 1]]},
        {"K": [["a", 0, 8], [0, 5, 8], [0, 0, 1]]},
        {"extrinsic": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]},
        {"extrinsic": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]},  # reflection
        {"extrinsic": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, float("nan")], [0, 0, 0, 1]]},
    ],
)
def test_bad_camera_entries_raise_input_error(tmp_path, changes):
    path = tmp_path / "cams.json"
    data = {"format": "garment-studio/cameras", "version": 1, "cameras": [_camera_dict(**changes)]}
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match="camera 0"):
        load_cameras(path)


def test_missing_camera_file(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_cameras(tmp_path / "none.json")


# --------------------------------------------------------------------------------------------
# viewer moves and keyed camera paths


def test_orbit_view_keeps_the_distance_and_turns_round_the_vertical():
    target = np.array([0.0, 0.9, 0.0])
    eye = np.array([0.0, 0.9, 2.5])
    turned = orbit_view(eye, target, math.pi / 2, 0.0)
    np.testing.assert_allclose(turned, [2.5, 0.9, 0.0], atol=1e-12)
    up = orbit_view(eye, target, 0.0, math.radians(30))
    assert np.linalg.norm(up - target) == pytest.approx(2.5)
    assert up[1] - 0.9 == pytest.approx(2.5 * math.sin(math.radians(30)))
    over = orbit_view(eye, target, 0.0, math.radians(170))  # clamped short of the pole
    assert math.degrees(math.asin((over[1] - 0.9) / 2.5)) == pytest.approx(85.0)
    with pytest.raises(InputError):
        orbit_view(target, target, 0.1, 0.0)


def test_pan_and_dolly_move_the_view_not_its_direction():
    eye, target = np.array([0.0, 1.0, 3.0]), np.array([0.0, 1.0, 0.0])
    e2, t2 = pan_view(eye, target, 0.5, 0.25)
    np.testing.assert_allclose(e2 - eye, [0.5, 0.25, 0.0], atol=1e-12)  # right is +x from +z
    np.testing.assert_allclose(t2 - target, e2 - eye, atol=1e-12)
    closer = dolly_view(eye, target, 0.5)
    np.testing.assert_allclose(closer, [0.0, 1.0, 1.5], atol=1e-12)
    assert np.linalg.norm(dolly_view(eye, target, 1e-6) - target) == pytest.approx(0.2)
    with pytest.raises(InputError):
        dolly_view(eye, target, 0.0)


def test_spherical_path_hits_the_keys_and_goes_round_the_body():
    target = np.array([0.0, 0.9, 0.0])
    front, back = target + [0.0, 0.0, 2.5], target + [0.0, 0.0, -2.5]
    side = target + [2.5, 0.0, 0.0]
    eyes, targets = np.stack([front, side, back]), np.stack([target] * 3)
    at = np.linspace(0.0, 2.0, 41)
    e, t = spherical_path(eyes, targets, np.array([0.0, 1.0, 2.0]), at)
    np.testing.assert_allclose(e[[0, 20, 40]], eyes, atol=1e-9)
    np.testing.assert_allclose(t, np.repeat(target[None], 41, 0), atol=1e-12)
    # a straight line front -> back would cross the body; the path keeps its distance
    np.testing.assert_allclose(np.linalg.norm(e - target, axis=1), 2.5, atol=1e-9)
    # smooth: no jump between samples larger than a few times the mean step
    steps = np.linalg.norm(np.diff(e, axis=0), axis=1)
    assert steps.max() < 1.5 * steps.mean()
    # distances between keys stay between the keys' (monotone: no overshoot)
    near = np.stack([target + [0.0, 0.0, 1.5], target + [1.5, 0.0, 0.0], target + [0, 0, -4.0]])
    e, _ = spherical_path(near, targets, np.array([0.0, 1.0, 2.0]), at)
    r = np.linalg.norm(e - target, axis=1)
    assert r.min() >= 1.5 - 1e-9 and r.max() <= 4.0 + 1e-9
    with pytest.raises(InputError):
        spherical_path(eyes, targets, np.array([0.0, 0.0, 1.0]), at)
    with pytest.raises(InputError):
        spherical_path(eyes[:0], targets[:0], np.zeros(0), at)
    one, _ = spherical_path(eyes[:1], targets[:1], np.zeros(1), at[:3])
    np.testing.assert_allclose(one, np.repeat(eyes[:1], 3, 0))
