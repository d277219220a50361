"""The torch-only render path: its rasterizer against the numpy reference, its import footprint,
its images against today's path (pipeline.playback), and CUDA against the CPU (``gpu``)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from core.camera import make_camera
from core.features import vertex_motion_features_torch
from core.raster import rasterize_reference
from tests.conftest import assert_close
from tests.test_raster import CAMERAS, check_invariants, compare_with_reference, scene_mesh, sphere
from training.torchpath import TorchCamera, TorchPlayer, load_bundle, pair_count, rasterize
from training.torchpath.shade import render_background

#: Pixel differences (0..255 levels) allowed between the torch path and today's path: the two
#: rasterizers disagree only at ties, which move single supersamples of the background and
#: single pixels of the proxy. Measured on the smoke project, 8 streamed frames at 128 and
#: 256 px: mean 0.0001 and 0.0002 levels, max 8 and 15 levels.
MEAN_LEVELS = 0.05
#: Share of pixels allowed to differ by more than 2 levels (measured: 0.0015% and 0.0029%).
FAR_SHARE = 0.001
#: Metres allowed between our Joint2Coarse in torch (float32 products in torch's order) and in
#: numpy: measured 1.8e-7 m at most on the smoke project's three motions (CPU).
OURS_ATOL = 1e-6
#: Metres allowed between the two paths' proxies after the strain limit Joint2Coarse's
#: predictions keep (core.strain.limit_stretch): an edge within rounding of its limit is
#: shortened in one path and not the other, and 30 sweeps spread that (1.8e-5 measured).
PROXY_ATOL = 5e-4

ALL_CAMERAS = [
    *CAMERAS,
    make_camera((0.3, 1.1, 1.6), (0, 0.9, 0), width=96, height=80, fov_y_deg=40),
]


def torch_fragments(v, f, cam, device="cpu", **kwargs):
    return rasterize(
        torch.from_numpy(v).to(device),
        torch.from_numpy(f).to(device),
        TorchCamera.from_camera(cam, device, kwargs.get("dtype", torch.float32)),
        **kwargs,
    )


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("cam_index", range(len(ALL_CAMERAS)))
def test_torch_raster_matches_reference(cam_index, dtype):
    v, f = scene_mesh()
    cam = ALL_CAMERAS[cam_index]
    ref = rasterize_reference(v, f, cam)
    out = torch_fragments(v, f, cam, dtype=dtype).numpy()
    check_invariants(out, len(f))
    assert out.mask.sum() > 0.1 * out.mask.size
    compare_with_reference(out, ref, v, f)
    same = (out.face_id == ref.face_id).mean()
    assert same >= 0.999, f"{same:.4%} of face ids match"
    if dtype == torch.float64:  # the reference's arithmetic: the same pixels
        assert np.array_equal(out.face_id, ref.face_id)


def test_torch_raster_inside_a_mesh_and_near_plane():
    v, f = sphere(0.5, 2)
    inside = make_camera((0.05, 1.1, 0.0), (0.3, 1.0, -1.0), width=32, height=24, fov_y_deg=80)
    out = torch_fragments(v, f, inside).numpy()
    assert out.mask.all()
    compare_with_reference(out, rasterize_reference(v, f, inside), v, f)
    cam = make_camera((0.0, 1.0, 2.0), (0, 1, 0), width=24, height=24, fov_y_deg=30)
    far = torch_fragments(v, f, cam, near=1.9).numpy()
    assert far.mask.sum() > 0 and (far.depth[far.mask] > 1.9).all()
    compare_with_reference(far, rasterize_reference(v, f, cam, near=1.9), v, f)


def test_torch_raster_batch_capacity_and_empty():
    v, f = scene_mesh()
    cam = ALL_CAMERAS[-1]
    tcam = TorchCamera.from_camera(cam)
    moved = v + np.float32([0.05, -0.02, 0.0])
    batch = torch.from_numpy(np.stack([v, moved]))
    faces = torch.from_numpy(f)
    one = [rasterize(batch[i], faces, tcam) for i in range(2)]
    both = rasterize(batch, faces, TorchCamera.stack([tcam, tcam]))
    for i in range(2):
        assert torch.equal(both.face_id[i], one[i].face_id)
        assert torch.equal(both.barycentrics[i], one[i].barycentrics)
    n = pair_count(batch[0], faces, tcam)
    fixed = rasterize(batch[0], faces, tcam, capacity=n + 100)
    assert not bool(fixed.overflow) and torch.equal(fixed.face_id, one[0].face_id)
    short = rasterize(batch[0], faces, tcam, capacity=n // 2)
    assert bool(short.overflow)
    empty = rasterize(torch.zeros(0, 3), torch.zeros(0, 3, dtype=torch.long), tcam)
    assert (empty.face_id == -1).all() and torch.isinf(empty.depth).all()


#: Modules a machine with only torch and numpy lacks, made absent while importing the path.
BLOCKED = (
    "open3d", "warp", "newton", "trimesh", "scipy", "PIL", "matplotlib", "tqdm", "imageio",
    "torchvision",
)  # fmt: skip


def test_import_needs_only_torch_and_numpy(tmp_path, ours_bundle):
    """The path imports, plays a bundle of our Joint2Coarse, and the torch-path render bench
    and the train bench run, with every other library absent (a ``None`` in ``sys.modules`` is
    what Python reports as not installed): what a machine with only torch and numpy sees."""
    code = f"""
import sys
for name in {BLOCKED!r}:
    sys.modules[name] = None
import training.torchpath
from app.cli import main
out = {str(tmp_path)!r}
player = training.torchpath.TorchPlayer({str(ours_bundle)!r})
player.set_clip(next(iter(player.clips)))
assert player.joint2coarse.config.model == "ours"
assert player.render(1, player.camera(1, 32, 32)).shape == (32, 32, 3)
assert main(["bench", "render", "--path", "torch", "--size", "24", "--threads", "1",
             "--frames", "1", "--batch", "1", "--presets", "tiny", "--out", out]) == 0
assert main(["bench", "train", "--preset", "tiny", "--size", "32", "--batch", "2",
             "--steps", "1", "--workers", "0", "--out", out]) == 0
assert all(sys.modules[name] is None for name in {BLOCKED!r})
print('ok')
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0 and res.stdout.strip().endswith("ok"), res.stderr
    assert (tmp_path / "render.json").is_file() and (tmp_path / "train.json").is_file()
    assert not (tmp_path / "render.png").exists()  # no matplotlib: the table only


def test_renderer_forward_bf16_close_to_fp32():
    from training.renderer import PRESETS, RenderNet

    torch.manual_seed(0)
    net = RenderNet(PRESETS["tiny"]).eval()
    g = torch.Generator().manual_seed(1)
    uv = torch.rand(1, 2, 32, 32, generator=g)
    motion = torch.rand(1, 95, 32, 32, generator=g)
    mask = (torch.rand(1, 1, 32, 32, generator=g) > 0.3).float()
    bg = torch.rand(1, 3, 32, 32, generator=g)
    with torch.no_grad():
        ref, _ = net(uv, motion, mask, uv, motion, mask, bg)
        with torch.autocast("cpu", torch.bfloat16):
            low, _ = net(uv, motion, mask, uv, motion, mask, bg)
    diff = (low.float() - ref).abs()
    # bf16 keeps 8 bits of mantissa: measured mean 5e-4, max 2.4e-3 (tiny and cpu presets).
    assert diff.mean() < 2e-3 and diff.max() < 2e-2, (float(diff.mean()), float(diff.max()))


@pytest.fixture(scope="module")
def bundle_file(smoke_project, tmp_path_factory):
    from pipeline.torch_export import export_bundle

    path = tmp_path_factory.mktemp("torchpath") / "smoke.torch.pt"
    export_bundle(smoke_project, path)
    return path


@pytest.fixture(scope="module")
def playback(smoke_project):
    from pipeline.playback import Playback, load_motion_for

    pb = Playback(smoke_project)
    pb.set_motion(load_motion_for(pb.project, pb.config.train_motion.name))
    return pb


@pytest.fixture(scope="module")
def ours_file(smoke_project):
    """The smoke project's own Joint2Coarse (model=ours), trained beside the paper's."""
    return smoke_project / "joint2coarse" / "compare-ours" / "joint2coarse.pt"


@pytest.fixture(scope="module")
def ours_bundle(smoke_project, ours_file, tmp_path_factory):
    from pipeline.torch_export import export_bundle

    path = tmp_path_factory.mktemp("torchpath") / "ours.torch.pt"
    export_bundle(smoke_project, path, frames=12, joint2coarse=ours_file)
    return path


@pytest.fixture(scope="module")
def ours_playback(smoke_project, ours_file):
    from pipeline.playback import Playback, load_motion_for

    pb = Playback(smoke_project, joint2coarse_path=ours_file)
    pb.set_motion(load_motion_for(pb.project, pb.config.train_motion.name, frames=12))
    return pb


def ours_descriptors(smoke_project, ours_file):
    """Our model and the descriptors of the smoke project's motions: (model, (N, D) float32)."""
    from pipeline.playback import Playback, load_motion_for
    from training.joint2coarse import joint2coarse_inputs, load_model, motion_descriptors

    model = load_model(ours_file)
    pb = Playback(smoke_project, joint2coarse_path=ours_file)
    descs = []
    for name in (pb.config.train_motion.name, *(m.name for m in pb.config.test_motions)):
        joints, root_rot = joint2coarse_inputs(load_motion_for(pb.project, name))
        descs.append(
            motion_descriptors(joints, root_rot, model.config.window, model.config.stride)[0]
        )
    return model, np.concatenate(descs)


def test_ours_in_torch_matches_numpy(smoke_project, ours_file):
    """One prediction, two libraries: BodyResidualNet (torch) against BodyResidualModel.predict
    (numpy), float64 descriptors and float32 ones."""
    model, desc = ours_descriptors(smoke_project, ours_file)
    ref = model.predict(desc)
    net = model.to_torch()
    assert_close(net(torch.from_numpy(desc)), ref, atol=OURS_ATOL, what="ours, torch float32 in")
    out = net(torch.from_numpy(desc.astype(np.float64)))
    assert out.dtype == torch.float32 and out.shape == ref.shape
    assert_close(out, ref, atol=OURS_ATOL, what="ours, torch float64 in")


def test_torch_path_plays_ours(ours_bundle, ours_playback):
    """A bundle of our Joint2Coarse: the proxy as the numpy path's, and its images."""
    pb = ours_playback
    player = TorchPlayer(ours_bundle)
    assert player.joint2coarse.config.model == "ours"
    player.set_clip(pb.config.train_motion.name)
    out = player.proxy(range(12))
    for t in range(12):  # PROXY_ATOL: the strain limit's thresholds amplify float rounding
        assert_close(out[t], pb.proxy_vertices(t), atol=PROXY_ATOL, what=f"ours proxy, frame {t}")
    diffs = []
    for t in range(3):
        cam = pb.default_camera(t, 96, 96, azimuth_deg=-20.0)
        assert player.camera(t, 96, 96, azimuth_deg=-20.0) == cam
        diffs.append(np.abs(player.render(t, cam).numpy().astype(int) - pb.render(t, cam)))
    d = np.stack(diffs)
    assert d.mean() < MEAN_LEVELS and (d > 2).mean() < FAR_SHARE, (d.mean(), (d > 2).mean())


def test_torch_path_matches_playback(bundle_file, playback):
    pb = playback
    player = TorchPlayer(bundle_file)
    player.set_clip(pb.config.train_motion.name)
    for t in range(3):
        assert_close(player.proxy([t])[0], pb.proxy_vertices(t), atol=PROXY_ATOL, what="proxy")
        assert_close(player.body([t])[0], pb.body_vertices(t), atol=1e-5, what="body")
    diffs = []
    encodes = pb.renderer.encodes
    for t in range(4):
        cam = pb.default_camera(t, 96, 96, azimuth_deg=30.0)
        assert player.camera(t, 96, 96, azimuth_deg=30.0) == cam
        ref = pb.render(t, cam)
        out = player.render(t, cam)
        assert out.dtype == torch.uint8 and out.shape == (96, 96, 3)
        diffs.append(np.abs(out.numpy().astype(int) - ref.astype(int)))
    d = np.stack(diffs)
    assert d.mean() < MEAN_LEVELS and (d > 2).mean() < FAR_SHARE, (d.mean(), (d > 2).mean())
    # Streamed as the numpy path: t-1's latent reused exactly when it is (same camera and box).
    assert player.encodes == pb.renderer.encodes - encodes


def test_torch_path_full_window_and_batch(bundle_file, playback):
    from training.renderer.inference import FrameState, NeuralRenderer
    from training.renderer.train import load_model

    pb = playback
    player = TorchPlayer(bundle_file, window="full")
    player.set_clip(pb.config.train_motion.name)
    cam = pb.default_camera(0, 64, 64)
    batch = player.render_batch(0, 3, cam)
    renderer = NeuralRenderer(load_model(pb.renderer_path)[1], pb.proxy_faces, pb.proxy_uvs)
    for t in range(3):
        streamed = player.render(t, cam)
        assert (streamed.int() - batch[t].int()).abs().max() <= 1  # batched BLAS rounding
        bg = pb.background(t, cam)
        prev = FrameState(pb.proxy_vertices(max(t - 1, 0)), pb.joint_window(max(t - 1, 0)), bg)
        frame = FrameState(pb.proxy_vertices(t), pb.joint_window(t), bg)
        ref = renderer.render_pair(cam, frame, prev, crop=False)
        d = np.abs(streamed.numpy().astype(int) - ref.astype(int))
        assert d.mean() < MEAN_LEVELS and (d > 2).mean() < FAR_SHARE, (d.mean(), (d > 2).mean())
    player.check_overflow()


def test_bad_bundle_names_the_file(tmp_path):
    from core.errors import InputError

    bad = tmp_path / "x.pt"
    bad.write_bytes(b"not a bundle")
    with pytest.raises(InputError, match="x.pt"):
        load_bundle(bad)
    with pytest.raises(InputError, match="missing.pt"):
        load_bundle(tmp_path / "missing.pt")


def test_torch_background_matches_numpy(playback):
    pb = playback
    cam = pb.default_camera(2, 80, 64, azimuth_deg=-40.0)
    ref = pb.background(2, cam)
    out = render_background(
        torch.from_numpy(pb.body_vertices(2).copy()),
        torch.from_numpy(pb.body_faces.copy()),
        TorchCamera.from_camera(cam),
    ).numpy()
    d = np.abs(out.astype(int) - ref.astype(int))
    assert d.mean() < MEAN_LEVELS and (d > 2).mean() < FAR_SHARE, (d.mean(), (d > 2).mean())


# -- CUDA against the CPU reference (skipped without a GPU) -----------------------------------


@pytest.mark.gpu
@pytest.mark.parametrize("cam_index", range(len(ALL_CAMERAS)))
def test_gpu_raster_matches_reference(cam_index):
    v, f = scene_mesh()
    cam = ALL_CAMERAS[cam_index]
    out = torch_fragments(v, f, cam, "cuda").numpy()
    ref = rasterize_reference(v, f, cam)
    check_invariants(out, len(f))
    compare_with_reference(out, ref, v, f)


@pytest.mark.gpu
def test_gpu_motion_features_match_cpu(rng):
    v = torch.from_numpy(rng.normal(size=(500, 3)).astype(np.float32))
    w = torch.from_numpy(rng.normal(size=(5, 19, 3)).astype(np.float32))
    cpu = vertex_motion_features_torch(v, w, 0.1)
    gpu = vertex_motion_features_torch(v.cuda(), w.cuda(), 0.1).cpu()
    assert_close(gpu, cpu, atol=1e-6, what="motion features")


@pytest.fixture
def no_tf32():
    """fp32 on the GPU as fp32 on the CPU: TF32 (10 bits of mantissa) off while a test runs."""
    saved = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False
    yield
    torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = saved


@pytest.mark.gpu
@pytest.mark.parametrize("bf16", [False, True])
def test_gpu_renderer_forward_matches_cpu(bf16, no_tf32):
    from training.renderer import PRESETS, RenderNet

    torch.manual_seed(0)
    net = RenderNet(PRESETS["cpu"]).eval()
    g = torch.Generator().manual_seed(1)
    args = [
        torch.rand(1, 2, 64, 64, generator=g),
        torch.rand(1, 95, 64, 64, generator=g),
        (torch.rand(1, 1, 64, 64, generator=g) > 0.3).float(),
    ]
    bg = torch.rand(1, 3, 64, 64, generator=g)
    with torch.no_grad():
        ref, _ = net(*args, *args, bg)
        net.cuda()
        with torch.autocast("cuda", torch.bfloat16, enabled=bf16):
            out, _ = net(*[a.cuda() for a in args + args], bg.cuda())
    diff = (out.float().cpu() - ref).abs()
    tol = (2e-3, 2e-2) if bf16 else (1e-5, 1e-4)
    assert diff.mean() < tol[0] and diff.max() < tol[1], (float(diff.mean()), float(diff.max()))


def synthetic_bundles(frames: int = 12) -> dict:
    """``dng bench render``'s synthetic bundle (the paper's network, random weights) and the
    same with our model (random rig and residual, the skirt as its rest proxy): torch and numpy
    only, so the ``gpu`` tests below run on a machine with nothing else."""
    from app.bench.render import synthetic_bundle
    from core.body.shape import mannequin_skeleton
    from training.joint2coarse import Joint2CoarseConfig, canonical_joint_order
    from training.joint2coarse.body_model import BodyResidualModel, motion_features
    from training.joint2coarse.descriptor import motion_descriptors
    from training.joint2coarse.model import MODEL_FORMAT

    paper = synthetic_bundle(frames)
    clip = paper["clips"]["synthetic"]
    cfg = Joint2CoarseConfig(model="ours")
    desc = motion_descriptors(
        clip["joints"].numpy(), clip["root_rotations"].numpy(), cfg.window, cfg.stride
    )[0]
    skel = mannequin_skeleton()
    rest = canonical_joint_order(skel.rest_positions()[None], skel.names)[0]
    g = np.random.default_rng(0)
    n = paper["joint2coarse"]["n_vertices"]
    weights = g.random((n, 20)) * (g.random(20) > 0.4)
    weights[:, 0] += 0.1
    feats = motion_features(desc, cfg.num_samples)
    arrays = {
        "weights": weights / weights.sum(1, keepdims=True),
        "rest_joints": rest - rest[0],
        "rest_vertices": g.normal(0.0, 0.2, (n, 3)),
        "feat_mean": feats.mean(0),
        "feat_std": np.maximum(feats.std(0), 1e-6),
        "coef": g.normal(0.0, 1e-3, (feats.shape[1] + 1, 3 * n)),
    }
    model = BodyResidualModel(cfg, desc.shape[1], arrays)
    payload = {
        "format": MODEL_FORMAT,
        "config": cfg.to_dict(),
        "n_vertices": n,
        "descriptor_dim": desc.shape[1],
        "state_dict": model.state_dict(),
    }
    return {"paper": paper, "ours": {**paper, "joint2coarse": payload}, "desc": desc}


def test_synthetic_ours_in_torch_matches_numpy():
    """The CPU side of the ``gpu`` Joint2Coarse tests: the synthetic bundle of our model plays
    its numpy prediction (measured 1.8e-7 m)."""
    from training.joint2coarse.model import net_from_payload

    bundles = synthetic_bundles()
    model = net_from_payload(bundles["ours"]["joint2coarse"])
    out = model.to_torch()(torch.from_numpy(bundles["desc"]))
    assert_close(out, model.predict(bundles["desc"]), atol=OURS_ATOL, what="ours")
    player = TorchPlayer(bundles["ours"])
    player.set_clip("synthetic")
    assert player.proxy(range(player.num_frames)).isfinite().all()


@pytest.mark.gpu
def test_gpu_ours_matches_numpy():
    """Our Joint2Coarse on CUDA against the numpy prediction (CPU)."""
    from training.joint2coarse.model import net_from_payload

    bundles = synthetic_bundles()
    model = net_from_payload(bundles["ours"]["joint2coarse"])
    out = model.to_torch().cuda()(torch.from_numpy(bundles["desc"]).cuda()).cpu()
    assert_close(out, model.predict(bundles["desc"]), atol=OURS_ATOL, what="ours on CUDA")


@pytest.mark.gpu
@pytest.mark.parametrize("model", ["paper", "ours"])
def test_gpu_joint2coarse_matches_cpu(model, no_tf32):
    """Joint2Coarse inside the player (descriptor on the device -> world proxy), CUDA against
    CPU, for the paper's network and ours."""
    bundle = synthetic_bundles()[model]
    cpu, gpu = TorchPlayer(bundle), TorchPlayer(bundle, "cuda")
    assert gpu.joint2coarse.config.model == model
    cpu.set_clip("synthetic")
    gpu.set_clip("synthetic")
    frames = range(cpu.num_frames)
    assert_close(gpu.proxy(frames).cpu(), cpu.proxy(frames), atol=1e-4, what=model)


@pytest.mark.gpu
def test_gpu_torch_path_matches_cpu(bundle_file, playback, no_tf32):
    pb = playback
    cpu = TorchPlayer(bundle_file)
    gpu = TorchPlayer(bundle_file, "cuda")
    name = pb.config.train_motion.name
    cpu.set_clip(name)
    gpu.set_clip(name)
    # Joint2Coarse on the GPU against the CPU.
    assert_close(gpu.proxy(range(4)).cpu(), cpu.proxy(range(4)), atol=1e-4, what="Joint2Coarse")
    for t in range(3):
        cam = pb.default_camera(t, 128, 128, azimuth_deg=30.0)
        d = np.abs(gpu.render(t, cam).cpu().numpy().astype(int) - cpu.render(t, cam).numpy())
        assert d.mean() < MEAN_LEVELS and (d > 2).mean() < FAR_SHARE, (d.mean(), (d > 2).mean())


def test_bench_render_torch_path_synthetic(tmp_path, dng):
    import json

    code, out, err = dng(
        "bench", "render", "--path", "torch", "--size", 32, "--threads", 1, "--frames", 2,
        "--batch", 2, "--presets", "tiny", "--out", tmp_path, "--json",
    )  # fmt: skip
    assert code == 0, err
    table = json.loads(out)
    (row,) = table["rows"]
    assert row["path"] == "torch" and row["size"] == 32 and row["batch"] == 2
    assert row["fps"] > 0 and row["batch_fps"] > 0 and row["joint2coarse_ms"] > 0
    assert row["torch"] == torch.__version__ and "cores" in row["device_name"]
    (j2c,) = table["joint2coarse_rows"]  # Joint2Coarse's own row, streamed and batched
    assert j2c["path"] == "torch" and j2c["model"] == "paper" and j2c["batch"] == 2
    assert j2c["ms_per_frame"] > 0 and j2c["batch_ms_per_frame"] > 0
    assert j2c["torch"] == torch.__version__ and j2c["device_name"] == row["device_name"]
    assert (tmp_path / "render.json").is_file()


def test_export_torch_cli(smoke_project, tmp_path, dng):
    out = tmp_path / "b.pt"
    code, text, err = dng("export", "torch", smoke_project, "--out", out, "--frames", 5)
    assert code == 0, err
    bundle = load_bundle(out)
    (clip,) = bundle["clips"].values()
    assert len(clip["joints"]) == 5 and "wrote" in text
    code, _, err = dng("export", "torch", tmp_path / "nothing", "--out", tmp_path / "c.pt")
    assert code == 2 and "nothing" in err and not (tmp_path / "c.pt").exists()
    code, _, err = dng("bench", "render", "--bundle", out, "--device", "cuda:0")
    assert code == 2 and ("CUDA" in err or torch.cuda.is_available())


def test_export_torch_cli_other_joint2coarse(smoke_project, ours_file, tmp_path, dng):
    out = tmp_path / "ours.pt"
    args = ("export", "torch", smoke_project, "--out", out, "--frames", 3, "--joint2coarse")
    code, _, err = dng(*args, ours_file)
    assert code == 0, err
    assert load_bundle(out)["joint2coarse"]["config"]["model"] == "ours"
    code, _, err = dng(*args[:3], "--out", tmp_path / "x.pt", *args[5:], tmp_path / "none.pt")
    assert code == 2 and "none.pt" in err and not (tmp_path / "x.pt").exists()


def test_the_strain_limit_in_torch_is_numpys():
    from core.strain import limit_stretch, stretch_limit
    from training.joint2coarse.synthetic import skirt_faces, synthetic_clip
    from training.torchpath.player import limit_stretch_torch

    _, _, proxy = synthetic_clip(4, seed=3)
    rest = proxy[0].astype(np.float64)
    frames = rest * np.array([1.0, 1.1, 1.0]) + 0.004 * np.random.default_rng(0).standard_normal(
        (4, *rest.shape)
    )  # stretched along y, and noise
    s = stretch_limit(rest, skirt_faces(), 0.01, 30)
    ref = limit_stretch(frames, s)
    out = limit_stretch_torch(
        torch.from_numpy(frames), torch.from_numpy(s.edges), torch.from_numpy(s.lengths), 0.01, 30
    )
    assert np.abs(ref - frames).max() > 1e-3  # it did shorten
    np.testing.assert_allclose(out.numpy(), ref, atol=1e-12)


def test_torch_background_matches_numpy_under_another_light(playback):
    """The torch path lights the body as the ray tracer does, environment light included."""
    from dataclasses import replace

    from core.lighting import PRESETS, environment_coefficients
    from core.mesh import Mesh
    from core.shading import ShadingConfig
    from core.shading import render_background as numpy_background

    radiance = np.zeros((16, 32, 3), np.float32)
    radiance[2:6, 4:12] = (6.0, 3.0, 1.0)
    lit = replace(PRESETS["low-sun"], environment=environment_coefficients(radiance))
    pb = playback
    cam = pb.default_camera(2, 80, 64, azimuth_deg=30.0)
    shading = ShadingConfig(lighting=lit)
    body = Mesh(pb.body_vertices(2), pb.body_faces)
    ref = numpy_background(body, cam, shading)
    out = render_background(
        torch.from_numpy(pb.body_vertices(2).copy()),
        torch.from_numpy(pb.body_faces.copy()),
        TorchCamera.from_camera(cam),
        shading,
    ).numpy()
    assert np.abs(ref.astype(int) - numpy_background(body, cam)).mean() > 5
    d = np.abs(out.astype(int) - ref.astype(int))
    assert d.mean() < MEAN_LEVELS and (d > 2).mean() < FAR_SHARE, (d.mean(), (d > 2).mean())
