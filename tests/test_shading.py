"""Ground-truth renders: deterministic, garment visible, lighting fixed to the camera, PNGs."""

from __future__ import annotations

import numpy as np
import pytest

from app.bench.raster import capsule_body, skirt_mesh
from core.camera import CameraRigConfig, make_camera, random_cameras
from core.errors import InputError
from core.mesh import Mesh
from core.shading import (
    Material,
    ShadingConfig,
    contact_sheet,
    render_background,
    render_ground_truth,
    render_views,
    to_uint8,
    vertex_normals,
    write_png,
)


@pytest.fixture(scope="module")
def scene():
    return skirt_mesh(rings=12, segments=24), capsule_body()[0]


CAM = make_camera((0.6, 1.3, 2.4), (0, 0.8, 0), width=48, height=64, fov_y_deg=40)
CFG = ShadingConfig(
    supersample=2,
    garment=Material(pattern="checker", pattern_color=(0.1, 0.2, 0.8), pattern_scale=4.0),
)


def test_render_is_deterministic_and_shows_the_garment(scene):
    skirt, body = scene
    a = render_ground_truth(skirt, body, CAM, CFG)
    b = render_ground_truth(skirt, body, CAM, CFG)
    for x, y in zip(
        (a.image, a.mask, a.coverage, a.background), (b.image, b.mask, b.coverage, b.background)
    ):
        assert np.array_equal(x, y)
    assert a.image.shape == (64, 48, 3) and a.image.dtype == np.uint8
    assert a.mask.dtype == bool and a.coverage.dtype == np.float32
    assert 0.05 < a.mask.mean() < 0.6
    assert np.array_equal(a.mask, a.coverage >= 0.5)
    # The garment differs from what is behind it (the body-only render) wherever it covers.
    full = a.coverage == 1
    diff = np.abs(a.image[full].astype(int) - a.background[full]).sum(-1)
    assert full.sum() > 100 and (diff > 30).mean() > 0.9
    # Both checker colours show up on the garment (UV pattern applied).
    red = a.image[a.mask][:, 0].astype(int) - a.image[a.mask][:, 2]
    assert (red > 60).mean() > 0.2 and (red < -30).mean() > 0.2


def test_background_is_the_body_alone(scene):
    skirt, body = scene
    gt = render_ground_truth(skirt, body, CAM, CFG)
    bg = render_background(body, CAM, CFG)
    assert np.array_equal(bg, gt.background)
    # Where no sample sees the garment, the image is the background.
    clear = gt.coverage == 0
    assert clear.mean() > 0.3
    assert np.abs(gt.image[clear].astype(int) - bg[clear]).max() <= 1
    # And the body is in the background image (not only the flat background colour).
    flat = to_uint8(np.asarray(CFG.background))
    assert (np.abs(bg.astype(int) - flat).sum(-1) > 30).mean() > 0.05


def test_lighting_turns_with_the_camera(scene):
    """Rotating the scene and the camera together leaves the image unchanged."""
    skirt, body = scene
    angle = np.radians(70.0)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    turned = [
        Mesh((m.vertices.astype(np.float64) @ rot.T).astype(np.float32), m.faces, m.uvs)
        for m in scene
    ]
    T = np.eye(4)
    T[:3, :3] = rot
    from core.camera import Camera

    cam2 = Camera(CAM.K, CAM.extrinsic @ T.T, CAM.width, CAM.height)  # T.T = T^-1 for a rotation
    a = render_ground_truth(skirt, body, CAM, CFG).image.astype(int)
    b = render_ground_truth(turned[0], turned[1], cam2, CFG).image.astype(int)
    diff = np.abs(a - b).max(-1)
    assert (diff > 2).mean() < 0.01, f"{(diff > 2).sum()} pixels differ"


def test_inside_of_open_cloth_is_lit(scene):
    skirt, _ = scene
    # From below, looking up into the skirt: we see the back faces of the cloth.
    cam = make_camera(
        (0.0, 0.2, 0.02), (0, 1.0, 0), width=32, height=32, fov_y_deg=60, up=(0, 0, 1)
    )
    gt = render_ground_truth(skirt, None, cam, ShadingConfig(supersample=1))
    assert gt.mask.mean() > 0.3
    assert gt.image[gt.mask].mean() > 25  # lit, not black
    flat = to_uint8(np.asarray(ShadingConfig().background))
    assert (gt.background == flat).all()  # no body: plain background


def test_supersampling_antialiases_edges(scene):
    skirt, body = scene
    hard = render_ground_truth(skirt, body, CAM, ShadingConfig(supersample=1))
    soft = render_ground_truth(skirt, body, CAM, ShadingConfig(supersample=3))
    assert set(np.unique(hard.coverage)) <= {0.0, 1.0}
    partial = (soft.coverage > 0) & (soft.coverage < 1)
    assert partial.sum() > 10  # the silhouette has fractional coverage
    assert np.abs(soft.mask.astype(int) - hard.mask).mean() < 0.05  # same garment region


def test_empty_view_is_all_background(scene):
    skirt, body = scene
    cam = make_camera((0, 1, 3), (0, 1, 8), width=16, height=12)
    gt = render_ground_truth(skirt, body, cam, CFG)
    flat = to_uint8(np.asarray(CFG.background))
    assert (gt.image == flat).all() and (gt.background == flat).all() and not gt.mask.any()


def test_render_views_matches_single_views(scene):
    skirt, body = scene
    cams = random_cameras(3, 5, CameraRigConfig(width=24, height=24))
    many = render_views(skirt, body, cams, CFG)
    for cam, gt in zip(cams, many):
        one = render_ground_truth(skirt, body, cam, CFG)
        assert np.array_equal(one.image, gt.image) and np.array_equal(one.background, gt.background)


def test_ray_casting_threads_do_not_change_the_images(scene):
    skirt, body = scene
    cams = random_cameras(2, 7, CameraRigConfig(width=32, height=40))
    every = render_views(skirt, body, cams, CFG)
    one = render_views(skirt, body, cams, ShadingConfig(**{**vars(CFG), "threads": 1}))
    for a, b in zip(every, one):
        assert np.array_equal(a.image, b.image) and np.array_equal(a.background, b.background)
        assert np.array_equal(a.coverage, b.coverage)


def test_bad_configs_raise(scene):
    skirt, body = scene
    with pytest.raises(InputError):
        Material(pattern="polka")
    with pytest.raises(InputError):
        Material(color=(1.2, 0, 0))
    with pytest.raises(InputError):
        ShadingConfig(supersample=0)
    with pytest.raises(InputError, match="threads must be an integer >= 0, got -1"):
        ShadingConfig(threads=-1)
    with pytest.raises(InputError, match="UVs"):
        render_ground_truth(Mesh(skirt.vertices, skirt.faces), body, CAM, CFG)


def test_vertex_normals_point_outwards_on_a_sphere():
    import trimesh

    m = trimesh.creation.icosphere(2)
    n = vertex_normals(m.vertices, m.faces)
    v = np.asarray(m.vertices) / np.linalg.norm(m.vertices, axis=1, keepdims=True)
    assert (np.einsum("vc,vc->v", n, v) > 0.99).all()


def test_png_writing(tmp_path):
    from PIL import Image

    rgb = np.random.default_rng(0).integers(0, 256, (10, 12, 3), dtype=np.uint8)
    write_png(tmp_path / "a.png", rgb)
    assert np.array_equal(np.asarray(Image.open(tmp_path / "a.png")), rgb)
    mask = rgb[..., 0] > 128
    write_png(tmp_path / "m.png", mask)
    assert np.array_equal(np.asarray(Image.open(tmp_path / "m.png")) > 0, mask)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "m.png"]
    with pytest.raises(InputError):
        write_png(tmp_path / "b.png", rgb.astype(np.float32))
    sheet = contact_sheet([rgb, mask], ["rgb", "mask"])
    assert sheet.dtype == np.uint8 and sheet.shape[1] > 2 * 12 and sheet.shape[2] == 3


def test_a_thin_layer_gives_partial_coverage_not_speckles():
    # A strip 0.4 px thick seen face-on, slanted by 2 px over the image's width, over the plain
    # background: one ray per pixel centre catches it in some columns and misses it in others (a
    # dashed line, the speckles of a thin layer); 3 x 3 rays per pixel see it in every column,
    # as pixels partly covered and partly coloured.
    cam = make_camera((0, 0, 2), (0, 0, 0), width=32, height=32, fov_y_deg=40)
    px = 2 * 2 * np.tan(np.radians(20)) / 32  # metres per pixel at the strip's depth
    x0, x1, t = -1.0, 1.0, 0.4 * px
    slope = 2 * px / (32 * px)
    verts = np.array(
        [[x0, 0.3 * px + slope * x0, 0], [x1, 0.3 * px + slope * x1, 0],
         [x1, 0.3 * px + slope * x1 + t, 0], [x0, 0.3 * px + slope * x0 + t, 0]],
        np.float32,
    )  # fmt: skip
    strip = Mesh(verts, np.array([[0, 1, 2], [0, 2, 3]], np.int64))
    flat = to_uint8(np.asarray(ShadingConfig().background)).astype(int)
    hard = render_ground_truth(strip, None, cam, ShadingConfig(supersample=1))
    soft = render_ground_truth(strip, None, cam, ShadingConfig(supersample=3))
    per_column_hard = hard.coverage.sum(0)
    per_column_soft = soft.coverage.sum(0)
    assert (per_column_hard == 0).any() and (per_column_hard > 0).any()  # dashed
    assert (per_column_soft > 0).all()  # continuous
    assert np.abs(per_column_soft - 0.4).max() <= 1 / 3 + 1e-6  # 0.4 px, to a sample row
    partial = (soft.coverage > 0) & (soft.coverage < 1)
    assert partial.any(0).all()  # every column is partly covered, none fully
    assert (soft.coverage < 1).all()
    changed = np.abs(soft.image.astype(int) - flat).sum(-1) > 0
    assert changed.any(0).all()  # the strip's colour shows in every column
