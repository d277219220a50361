"""Rasterizer: Open3D fast path vs the numpy reference, invariants, hard views, the benchmark."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from core.camera import make_camera, pixel_rays, project, resize_camera
from core.errors import InputError
from core.raster import (
    Fragments,
    MeshScene,
    RasterConfig,
    candidate_pixels,
    rasterize,
    rasterize_reference,
)
from tests.conftest import assert_close


def sphere(radius=0.5, subdivisions=2, center=(0.0, 1.0, 0.0)):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions, radius=radius)
    return np.asarray(m.vertices, np.float32) + np.float32(center), np.asarray(m.faces, np.int64)


def open_skirt(rings=8, segments=16):
    """A flared open cylinder (both sides visible), waist at y = 1.2, hem at y = 0.6."""
    s = np.linspace(0, 1, rings)
    th = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    r = 0.2 + 0.25 * s
    v = np.stack(
        [
            np.outer(r, np.sin(th)),
            np.repeat((1.2 - 0.6 * s)[:, None], segments, 1),
            np.outer(r, np.cos(th)),
        ],
        -1,
    ).reshape(-1, 3)
    f = []
    for i in range(rings - 1):
        for j in range(segments):
            a, b = i * segments + j, i * segments + (j + 1) % segments
            f += [[a, a + segments, b], [b, a + segments, b + segments]]
    return v.astype(np.float32), np.array(f, np.int64)


def scene_mesh():
    """A skirt around a sphere: occlusion, open boundaries, back faces."""
    vs, fs = sphere(0.18, 2, (0.0, 0.95, 0.0))
    vk, fk = open_skirt()
    return np.concatenate([vk, vs]), np.concatenate([fk, fs + len(vk)])


CAMERAS = [
    make_camera((0.0, 1.0, 2.5), (0, 0.9, 0), width=64, height=48, fov_y_deg=40),
    make_camera((1.2, 2.2, 1.0), (0, 0.9, 0), width=40, height=56, fov_y_deg=50),  # above: inside
    make_camera((-0.4, 0.2, 0.9), (0, 1.0, 0), width=48, height=48, fov_y_deg=70),  # below: inside
]


def check_invariants(fr: Fragments, num_faces: int) -> None:
    h, w = fr.face_id.shape
    assert fr.face_id.dtype == np.int64 and fr.barycentrics.dtype == np.float32
    assert fr.depth.dtype == np.float32 and fr.mask.dtype == bool
    assert fr.barycentrics.shape == (h, w, 3) and fr.depth.shape == (h, w)
    m = fr.mask
    assert (fr.face_id[m] < num_faces).all() and (fr.face_id[~m] == -1).all()
    b = fr.barycentrics[m]
    assert (b >= 0).all() and (b <= 1).all()
    assert_close(b.sum(-1), np.ones(len(b)), atol=1e-6, what="barycentric sums")
    assert (fr.barycentrics[~m] == 0).all()
    assert (
        np.isinf(fr.depth[~m]).all() and np.isfinite(fr.depth[m]).all() and (fr.depth[m] > 0).all()
    )


def compare_with_reference(fast: Fragments, ref: Fragments, vertices, faces) -> None:
    """Face ids agree except at edge/silhouette ties; barycentrics and depths close."""
    total = fast.mask | ref.mask
    differ = fast.face_id != ref.face_id
    assert differ.sum() <= max(2, 0.02 * total.sum()), (
        f"{differ.sum()} of {total.sum()} pixels differ"
    )
    for i, j in zip(*np.nonzero(differ)):
        # A pixel may only differ when its sample lies on an edge of a triangle one of the two
        # rasterizers chose (within float32 precision), or when both see the same depth (a tie).
        on_edge = [fr.mask[i, j] and fr.barycentrics[i, j].min() < 2e-3 for fr in (fast, ref)]
        tie = fast.mask[i, j] and ref.mask[i, j] and abs(fast.depth[i, j] - ref.depth[i, j]) < 1e-4
        assert any(on_edge) or tie, (
            f"pixel {(i, j)}: faces {fast.face_id[i, j]} vs {ref.face_id[i, j]}"
        )
    same = ~differ & fast.mask
    assert_close(fast.barycentrics[same], ref.barycentrics[same], atol=5e-4, what="barycentrics")
    assert_close(fast.depth[same], ref.depth[same], atol=1e-5, rtol=1e-5, what="depth")


@pytest.mark.parametrize("cam_index", range(len(CAMERAS)))
def test_open3d_matches_reference(cam_index):
    v, f = scene_mesh()
    cam = CAMERAS[cam_index]
    fast = rasterize(v, f, cam)
    ref = rasterize_reference(v, f, cam)
    check_invariants(fast, len(f))
    check_invariants(ref, len(f))
    assert fast.mask.sum() > 0.1 * fast.mask.size
    compare_with_reference(fast, ref, v, f)


def test_tile_culling_changes_nothing():
    v, f = scene_mesh()
    for cam in CAMERAS + [resize_camera(CAMERAS[0], 131, 77)]:
        culled = rasterize(v, f, cam, RasterConfig(tile=8))
        full = rasterize(v, f, cam, RasterConfig(tile=0))
        assert np.array_equal(culled.face_id, full.face_id)
        assert np.array_equal(culled.barycentrics, full.barycentrics)
        assert np.array_equal(culled.depth, full.depth)
        assert len(candidate_pixels(v, f, cam)) < cam.width * cam.height or cam is CAMERAS[2]


def test_hits_reproject_to_their_pixel_centres():
    """Projection and rasterization agree: the hit seen at pixel (i, j) projects to its centre."""
    v, f = scene_mesh()
    cam = make_camera((0.6, 1.4, 1.9), (0, 0.9, 0), width=96, height=80, fov_y_deg=35)
    fr = rasterize(v, f, cam)
    i, j = np.nonzero(fr.mask)
    corners = v[f[fr.face_id[i, j]]].astype(np.float64)
    hit = np.einsum("nk,nkc->nc", fr.barycentrics[i, j].astype(np.float64), corners)
    uv, depth = project(hit, cam)
    assert_close(uv, np.stack([j + 0.5, i + 0.5], 1), atol=2e-3, what="reprojected hit (pixels)")
    assert_close(depth, fr.depth[i, j], atol=1e-5, rtol=1e-5, what="depth")


def test_visible_vertex_projects_to_the_pixel_whose_ray_hits_it():
    v, f = sphere(0.5, 2)
    cam = make_camera((0.3, 1.2, 2.5), (0, 1, 0), width=128, height=128, fov_y_deg=35)
    fr = rasterize(v, f, cam)
    # On a convex sphere the vertices facing the camera are the visible ones.
    to_cam = cam.center - v
    normal = v - np.array([0, 1, 0])
    cos = np.einsum("vc,vc->v", to_cam, normal) / (np.linalg.norm(to_cam, axis=1) * 0.5)
    visible = cos > 0.5
    uv, depth = project(v[visible], cam)
    col, row = np.floor(uv).astype(int).T
    assert fr.mask[row, col].all()
    # The pixel's hit is within about a pixel's footprint (on the tilted surface) of the vertex.
    corners = v[f[fr.face_id[row, col]]]
    hit = np.einsum("nk,nkc->nc", fr.barycentrics[row, col], corners)
    footprint = depth / cam.fx / cos[visible]
    assert (np.linalg.norm(hit - v[visible], axis=1) < 1.5 * footprint).all()
    # A ray through the exact projection hits the vertex itself.
    origin, d = pixel_rays(cam, uv)
    t, face, _ = MeshScene(v, f).cast(origin, d)
    assert (face >= 0).all()
    assert_close(t, depth, atol=1e-5, rtol=1e-5, what="ray parameter vs vertex depth")


def test_both_sides_of_an_open_surface_are_hit():
    v = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], np.float32)
    f = np.array([[0, 2, 1], [0, 3, 2]])  # normal +Y
    kw = dict(width=16, height=16, fov_y_deg=30, up=(0, 0, -1))
    above = make_camera((0.0, 3.0, 0.0), (0, 0, 0), **kw)
    below = make_camera((0.0, -3.0, 0.0), (0, 0, 0), **kw)
    for cam in (above, below):
        fr = rasterize(v, f, cam)
        assert fr.mask.all()
        assert_close(fr.depth, np.full((16, 16), 3.0), atol=1e-3, what="depth")
        compare_with_reference(fr, rasterize_reference(v, f, cam), v, f)


def test_camera_inside_a_closed_mesh_sees_its_inside():
    v, f = sphere(0.5, 2)
    cam = make_camera((0.05, 1.1, 0.0), (0.3, 1.0, -1.0), width=32, height=24, fov_y_deg=80)
    fr = rasterize(v, f, cam)
    assert fr.mask.all()
    check_invariants(fr, len(f))
    assert len(candidate_pixels(v, f, cam)) == 32 * 24  # triangles cross the camera plane
    compare_with_reference(fr, rasterize_reference(v, f, cam), v, f)


def test_near_plane_clips_close_surfaces():
    v, f = sphere(0.5, 2)
    cam = make_camera((0.0, 1.0, 2.0), (0, 1, 0), width=24, height=24, fov_y_deg=30)
    far_only = rasterize(v, f, cam, RasterConfig(near=1.9))
    ref = rasterize_reference(v, f, cam, near=1.9)
    check_invariants(far_only, len(f))
    assert far_only.mask.sum() > 0 and (far_only.depth[far_only.mask] > 1.9).all()
    compare_with_reference(far_only, ref, v, f)
    front = rasterize(v, f, cam)
    assert far_only.depth[far_only.mask].min() > front.depth[front.mask].min() + 0.3  # back half


@pytest.mark.parametrize(
    "eye,target",
    [((0, 1, 3), (0, 1, 6)), ((20, 1, 0), (30, 1, 0)), ((0, 1, 3), (5, 1, 3))],
)
def test_empty_views(eye, target):
    v, f = scene_mesh()
    cam = make_camera(eye, target, width=20, height=10)
    fr = rasterize(v, f, cam)
    assert not fr.mask.any() and (fr.face_id == -1).all() and np.isinf(fr.depth).all()
    assert (fr.barycentrics == 0).all()
    assert not rasterize_reference(v, f, cam).mask.any()


def test_empty_mesh_gives_background():
    cam = make_camera((0, 1, 3), (0, 1, 0), width=8, height=6)
    fr = rasterize(np.zeros((0, 3)), np.zeros((0, 3), np.int64), cam)
    assert fr.face_id.shape == (6, 8) and not fr.mask.any()


def test_scene_is_reused_across_cameras():
    v, f = scene_mesh()
    scene = MeshScene(v, f).build()
    for cam in CAMERAS:
        a = rasterize(v, f, cam, scene=scene)
        b = rasterize(v, f, cam)
        assert np.array_equal(a.face_id, b.face_id) and np.array_equal(a.depth, b.depth)


def test_bad_meshes_raise_input_error():
    cam = CAMERAS[0]
    v, f = sphere()
    bad_v = v.copy()
    bad_v[3] = np.nan
    with pytest.raises(InputError):
        rasterize(bad_v, f, cam)
    with pytest.raises(InputError):
        rasterize(v, f + len(v), cam)
    with pytest.raises(InputError):
        rasterize(v[:, :2], f, cam)
    with pytest.raises(InputError):
        RasterConfig(near=-1.0)


def test_bench_raster_runs_and_reports(capsys, tmp_path):
    from app.bench import raster as bench

    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    args = parser.parse_args(
        [
            "--sizes",
            "32",
            "48",
            "--repeats",
            "1",
            "--views",
            "2",
            "--json",
            "--ground-truth",
            "--out",
            str(tmp_path),
        ]
    )
    assert bench.run(args) == 0
    report = json.loads(capsys.readouterr().out)
    assert json.loads((tmp_path / "raster.json").read_text()) == report
    assert (tmp_path / "raster.png").stat().st_size > 0
    assert [g["size"] for g in report["ground_truth"]] == [32, 48]
    assert all(g["per_view_ms"] > 0 for g in report["ground_truth"])
    assert [(r["framing"], r["size"]) for r in report["results"]] == [
        ("body", 32),
        ("body", 48),
        ("garment", 32),
        ("garment", 48),
    ]
    assert report["proxy_vertices"] == 2040 and report["feature_channels"] == 95
    for r in report["results"]:
        assert r["per_view_ms"] > 0 and 0 < r["coverage"] < 1
