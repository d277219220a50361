"""pipeline.playback: motions, shapes, cameras, streaming renders; compositing for fine-tuning;
frame writers."""

from __future__ import annotations

import imageio_ffmpeg
import numpy as np
import pytest
import torch

from core.camera import make_camera
from core.compositing import fit_image, recomposite, surface_coverage
from core.errors import InputError
from pipeline.playback import FrameWriter, Playback, load_motion_for
from tests.conftest import assert_close

SIZE = 64


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def playback(smoke_project) -> Playback:
    pb = Playback(smoke_project)
    pb.set_motion(load_motion_for(pb.project, "dance", frames=8))
    return pb


def test_motion_sources(smoke_project, bvh_dir):
    from core.body.shape import mannequin_skeleton
    from core.project import Project
    from pipeline.config import project_config

    config = project_config(Project(smoke_project))
    names = tuple(mannequin_skeleton(config.body).names)
    own = load_motion_for(smoke_project, "dance", frames=5)
    assert own.num_frames == 5 and own.meta["project_motion"] == "dance"
    walk = load_motion_for(smoke_project, "walk", frames=7, seed=3)
    assert walk.num_frames == 7 and "project_motion" not in walk.meta
    cmu = load_motion_for(smoke_project, bvh_dir / "01_01.bvh", frames=10)
    assert cmu.num_frames == 10 and cmu.fps == pytest.approx(config.fps)
    for m in (own, walk, cmu):
        assert tuple(m.skeleton.names) == names
    with pytest.raises(InputError, match="no such motion"):
        load_motion_for(smoke_project, "moonwalk")
    with pytest.raises(InputError, match="frames wanted") as e:
        load_motion_for(smoke_project, "dance", frames=10_000)
    assert "dance.bvh" in str(e.value)
    with pytest.raises(InputError, match="not found"):
        load_motion_for(smoke_project, smoke_project / "missing.bvh")


def test_shapes(playback):
    pb = playback
    assert pb.num_frames == 8 and pb.fps == pytest.approx(pb.config.fps)
    vb = pb.body_vertices(3)
    assert vb.shape == (len(pb.body.vertices), 3) and vb.dtype == np.float32
    assert pb.body_faces.max() < len(vb)
    vp = pb.proxy_vertices(3)
    assert vp.dtype == np.float32 and vp.shape == (len(pb.proxy_uvs), 3)
    assert pb.proxy_faces.max() < len(vp)
    assert_close(vp, pb.proxy_positions(3)[pb.seam_map], what="UV-split proxy")
    assert pb.joint_window(3).shape == (5, 19, 3)
    with pytest.raises(InputError, match="out of range"):
        pb.proxy_vertices(8)
    cam = pb.default_camera(3, 48, 40, azimuth_deg=90)
    assert (cam.width, cam.height) == (48, 40)
    bg = pb.background(3, cam)
    assert bg.shape == (40, 48, 3) and bg.dtype == np.uint8
    # The camera frames the garment: the proxy projects inside the image.
    from core.camera import project

    uv, depth = project(vp.astype(np.float64), cam)
    assert (depth > 0).all()
    inside = (uv[:, 0] >= 0) & (uv[:, 0] <= 48) & (uv[:, 1] >= 0) & (uv[:, 1] <= 40)
    assert inside.mean() > 0.95


def test_render_and_streaming(playback, smoke_project):
    pb = playback
    cam = pb.default_camera(2, SIZE, SIZE, azimuth_deg=30)
    pb.renderer.reset()
    start = pb.renderer.encodes
    calls = []  # (frame, previous) as the renderer got them
    render = pb.renderer.render
    pb.renderer.render = lambda c, f, p=None: calls.append((f, p)) or render(c, f, p)
    try:
        images = [pb.render(t, cam) for t in range(2, 6)]
    finally:
        del pb.renderer.render
    encodes = pb.renderer.encodes - start
    # Frame t-1 is passed as the very object the renderer saw, so its latent can be reused.
    assert all(prev is calls[i][0] for i, (_, prev) in enumerate(calls[1:]))
    # It is reused exactly where the crop box stays put (the first frame encodes t-1 too).
    boxes = [pb.renderer.crop_box(cam, f) for f, _ in calls]
    assert encodes == 2 + sum(1 if a == b else 2 for a, b in zip(boxes, boxes[1:]))
    assert set(pb.last_timings) >= {"joint2coarse", "background", "raster+network", "total"}
    img = images[-1]
    bg = pb.background(5, cam)
    assert img.shape == (SIZE, SIZE, 3) and img.dtype == np.uint8
    box = pb.renderer.crop_box(cam, _frame(pb, 5, bg))
    inside = np.zeros((SIZE, SIZE), bool)
    inside[max(box.y0, 0) : box.y0 + box.height, max(box.x0, 0) : box.x0 + box.width] = True
    assert (img[~inside] == bg[~inside]).all()  # outside the network's crop: the background
    diff = np.abs(img.astype(int) - bg.astype(int)).sum(-1)
    assert (diff[inside] > 0).mean() > 0.2  # the garment is drawn
    assert img.std() > 1.0
    # Streaming never changes pixels: frame 5 alone (t-1 encoded afresh) is the same image.
    fresh = Playback(smoke_project)
    fresh.set_motion(pb.motion)
    assert_close(fresh.render(5, cam), img, atol=1, what="streamed vs stateless frame")


def _frame(pb, t, bg):
    from training.renderer.inference import FrameState

    return FrameState(pb.proxy_vertices(t), pb.joint_window(t), bg)


def test_missing_renderer_proxy_only(smoke_project, tmp_path):
    missing = tmp_path / "nowhere" / "renderer.pt"
    pb = Playback(smoke_project, renderer_path=missing)
    pb.set_motion(load_motion_for(pb.project, "walk", frames=3))
    cam = pb.default_camera(1, 32, 32)
    assert pb.background(1, cam).shape == (32, 32, 3)
    assert pb.proxy_image(1, cam).shape == (32, 32, 3)
    assert not pb.has_renderer()
    with pytest.raises(InputError, match="no trained renderer") as e:
        pb.render(1, cam)
    assert str(missing) in str(e.value)


def test_missing_project(tmp_path):
    with pytest.raises(InputError, match="not found"):
        Playback(tmp_path / "none")
    with pytest.raises(InputError, match="project.json"):
        Playback(tmp_path)


def test_simulated_reference(playback):
    sim = playback.simulated_proxy("dance")
    assert sim is not None and sim.shape[1:] == playback.proxy_positions(0).shape
    assert playback.simulated_proxy("no-such-motion") is None
    cam = playback.default_camera(1, 32, 32)
    image, label = playback.reference_image(1, cam)
    assert image.shape == (32, 32, 3) and label == "simulation"


def test_backdrop(playback):
    cam = playback.default_camera(1, 32, 32)
    plain = playback.background(1, cam)
    backdrop = np.zeros((20, 50, 3), np.uint8)
    backdrop[..., 1] = 255
    playback.set_backdrop(backdrop)
    try:
        green = playback.background(1, cam)
    finally:
        playback.set_backdrop(None)
    body = surface_coverage(playback.body_vertices(1), playback.body_faces, cam, 3) > 0
    assert (green[~body] == [0, 255, 0]).all()
    full = surface_coverage(playback.body_vertices(1), playback.body_faces, cam, 3) >= 1
    assert np.abs(green[full].astype(int) - plain[full]).max() <= 1  # the body is unchanged


# ------------------------------------------------------------------- compositing (no project)


def _scene():
    from core.mesh import Mesh

    v = np.array([[-0.3, 0.6, 0], [0.3, 0.6, 0], [0, 1.1, 0], [0.3, 1.1, 0]], np.float32)
    f = np.array([[0, 1, 2], [1, 3, 2]])
    cam = make_camera((0.0, 0.85, 2.0), (0.0, 0.85, 0.0), width=24, height=20)
    return Mesh(v, f), cam


def test_surface_coverage_matches_shading():
    from core.shading import render_views

    mesh, cam = _scene()
    gt = render_views(mesh, None, [cam])[0]
    cov = surface_coverage(mesh.vertices, mesh.faces, cam, 3)
    assert cov.shape == (20, 24) and cov.dtype == np.float32
    assert_close(cov, gt.coverage, atol=1e-6, what="coverage")
    assert 0 < cov.mean() < 1 and ((cov > 0) & (cov < 1)).any()  # edges are fractional


def test_recomposite_is_exact_where_it_can_be():
    from core.shading import ShadingConfig, render_views

    mesh, cam = _scene()
    config = ShadingConfig()
    gt = render_views(mesh, None, [cam], config)[0]
    cov = surface_coverage(mesh.vertices, mesh.faces, cam, config.supersample)
    back = np.random.default_rng(0).integers(0, 256, (20, 24, 3), dtype=np.uint8)
    out = recomposite(gt.image, cov, config.background, back)
    assert (out[cov == 0] == back[cov == 0]).all()
    assert (out[cov == 1] == gt.image[cov == 1]).all()
    # Over the clear colour itself nothing changes (up to 8-bit rounding).
    clear = np.empty_like(back)
    clear[:] = np.rint(np.asarray(config.background) * 255).astype(np.uint8)
    same = recomposite(gt.image, cov, config.background, clear)
    assert np.abs(same.astype(int) - gt.image).max() <= 1
    # A render made over another colour is what recompositing gives (edges included).
    other = ShadingConfig(background=(0.1, 0.5, 0.2))
    direct = render_views(mesh, None, [cam], other)[0].image
    flat = np.empty_like(back)
    flat[:] = np.rint(np.asarray(other.background) * 255).astype(np.uint8)
    swapped = recomposite(gt.image, cov, config.background, flat)
    assert np.abs(swapped.astype(int) - direct).max() <= 2


def test_fit_image():
    im = np.arange(30 * 60 * 3, dtype=np.uint32).reshape(30, 60, 3).astype(np.uint8)
    out = fit_image(im, 20, 20)
    assert out.shape == (20, 20, 3) and out.dtype == np.uint8
    assert fit_image(im, 60, 30) is im


# ------------------------------------------------------------------------------ frame writers


def _frames(n=3, h=15, w=21):
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(n)]


def test_writer_png_folder(tmp_path):
    from PIL import Image

    out = tmp_path / "frames"
    with FrameWriter(f"{out}/", fps=10) as w:
        for f in _frames(3):
            w.append(f)
    names = sorted(p.name for p in out.iterdir())
    assert names == ["frame_00000.png", "frame_00001.png", "frame_00002.png"]
    assert (np.asarray(Image.open(out / "frame_00001.png")) == _frames(3)[1]).all()
    with FrameWriter(out, fps=10) as w:  # an existing folder: stale frames go
        w.append(_frames(1)[0])
    assert sorted(p.name for p in out.iterdir()) == ["frame_00000.png"]


def test_writer_gif_and_mp4(tmp_path):
    from PIL import Image

    with FrameWriter(tmp_path / "a.gif", fps=20) as w:
        for f in _frames(4):
            w.append(f)
    with Image.open(tmp_path / "a.gif") as g:
        assert g.n_frames == 4 and g.size == (21, 15)
    with FrameWriter(tmp_path / "a.mp4", fps=12) as w:
        for f in _frames(5):
            w.append(f)
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "a.mp4"))
    meta = next(reader)
    assert meta["size"] == (22, 16)  # padded to even sizes for H.264
    assert sum(1 for _ in reader) == 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "a.mp4"]  # no temporaries


def test_writer_is_atomic(tmp_path):
    for name in ("b.gif", "b.mp4", "dir/"):
        with pytest.raises(RuntimeError), FrameWriter(tmp_path / name, fps=5) as w:
            w.append(_frames(1)[0])
            raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="unsupported output"):
        FrameWriter(tmp_path / "x.avi", fps=5)
    with pytest.raises(InputError, match="same|size"), FrameWriter(tmp_path / "c.gif", 5) as w:
        w.append(_frames(1)[0])
        w.append(_frames(1, h=16)[0])
    assert list(tmp_path.iterdir()) == []
