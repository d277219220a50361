"""``dng bench render``: live neural rendering speed, ms per frame by part, against fps targets.

One frame of playback is: Joint2Coarse streaming (one descriptor + one network pass,
:class:`training.joint2coarse.Joint2CoarseStream`), rasterizing the proxy and making the UV and
motion-feature maps (``raster+feat``), and the renderer network on the crop around the proxy
(``network``: texture sample, encode frame t once, t-1's latent reused, decode, paste over the
background). ``fps`` counts these three; the body-only background (``background``, measured
only with ``--project``: it is a ray-traced render of the body) is reported beside it.

Setups: ``--project DIR`` uses a trained project (its Joint2Coarse, its renderer model or a
preset with random weights, its training motion and the data set's camera framing); without
it, a synthetic skirt proxy (about 2k vertices, :func:`training.renderer.synthetic_scene`) over
a flat background, with random weights at the preset's sizes (speed does not depend on the
weights) and a paper-sized Joint2Coarse on a synthetic walk.

Paths (``--path``): ``numpy`` is today's playback (Embree rasterizer, numpy features, the
network on ``--device``); ``torch`` is :class:`training.torchpath.TorchPlayer`, everything on
the device from a bundle (``--bundle FILE`` from ``dng export torch``, or made from
``--project``, or a synthetic one): Joint2Coarse, the body background (part of each frame
there), rasterization, features and network, with nothing but scalars read back. The torch path
also reports batched throughput (``--batch N`` consecutive frames per call, background
included). Every row names the device and the torch version.

Targets: >= 10 fps at 128 px and >= 3 fps at 256 px on 2 CPU cores (the ``cpu`` preset);
>= 100 fps at 512 px and >= 300 fps at 256 px on a GPU (``--device cuda``, the ``paper``
preset), Joint2Coarse under 0.5 ms per frame there.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.bench import add_output_arguments
from core.camera import crop_camera, make_camera
from core.errors import InputError
from core.features import FeatureConfig, joint_window
from core.fileio import atomic_path, write_json
from pipeline.playback import Playback, load_motion_for

HELP = "neural rendering: Joint2Coarse + raster/features + network ms per frame vs fps targets"

#: (device type, preset, size) -> frames per second to reach.
TARGETS_FPS = {
    ("cpu", "cpu", 128): 10.0,
    ("cpu", "cpu", 256): 3.0,
    ("cuda", "paper", 256): 300.0,
    ("cuda", "paper", 512): 100.0,
}
#: Joint2Coarse ms per frame to stay under on a GPU.
TARGET_J2C_MS_CUDA = 0.5
#: Timed frames after the warm-up ones.
DEFAULT_FRAMES = 12
WARMUP = 2


@dataclass
class BenchSetup:
    """What one frame of playback needs, for every frame of a short clip.

    Attributes
    ----------
    name : "synthetic" or the project folder
    proxy : (T, Vp, 3) float32 UV-split proxy vertices (what is rasterized)
    faces : (F, 3) int64; uvs : (Vp, 2) float32
    windows : (T, K, 19, 3) float32 joint windows of the motion features
    joints : (T, 20, 3) float32 and root_rotations : (T, 3, 3) float32, Joint2Coarse's inputs
    joint2coarse : a Joint2CoarseNet
    camera : size -> Camera framing the garment at frame 0
    background : (t, camera) -> (H, W, 3) uint8
    model : trained RenderNet of a project (None: presets with random weights only)
    measures_background : whether ``background`` is the real (ray-traced) one
    stretch : the strain limit a project's Joint2Coarse keeps (None: the synthetic setup's)
    """

    name: str
    proxy: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    windows: np.ndarray
    joints: np.ndarray
    root_rotations: np.ndarray
    joint2coarse: object
    camera: object
    background: object
    model: object = None
    measures_background: bool = False
    stretch: object = None


def synthetic_setup(frames: int, resolution: int = 64) -> BenchSetup:
    """The synthetic skirt (``resolution`` columns: about 2k vertices at 64) over a flat grey."""
    import torch

    from training.joint2coarse import Joint2CoarseConfig, joint2coarse_inputs
    from training.joint2coarse.model import Joint2CoarseNet
    from training.joint2coarse.synthetic import synthetic_walk
    from training.renderer import synthetic_scene

    scene = synthetic_scene(frames, resolution=resolution, seed=0)
    config = Joint2CoarseConfig()
    torch.manual_seed(0)
    net = Joint2CoarseNet(config, scene.proxy.shape[1], config.num_samples * 57).eval()
    joints, root_rot = joint2coarse_inputs(synthetic_walk(frames, seed=0))
    windows = np.stack([joint_window(scene.joints, t) for t in range(frames)])

    def camera(size: int):
        return make_camera((0.0, 0.85, 2.2), (0.0, 0.75, 0.0), width=size, height=size)

    def background(t: int, cam) -> np.ndarray:
        return np.full((cam.height, cam.width, 3), 200, np.uint8)

    return BenchSetup(
        "synthetic", scene.proxy, scene.faces, scene.uvs, windows, joints, root_rot, net,
        camera, background,
    )  # fmt: skip


def project_setup(root, frames: int) -> BenchSetup:
    """A trained project: its training motion (procedural when shorter than ``frames``)."""
    from training.joint2coarse import joint2coarse_inputs

    pb = Playback(root)
    name = pb.config.train_motion.name
    motion = load_motion_for(pb.project, name)
    kind = pb.config.train_motion.kind
    if motion.num_frames < frames and kind != "file":
        motion = load_motion_for(pb.project, kind, frames=frames)  # same kind, long enough
    pb.set_motion(motion)
    n = min(frames, pb.num_frames)
    joints, root_rot = joint2coarse_inputs(motion)
    model = None
    if pb.has_renderer():
        from training.renderer.train import load_model

        model = load_model(pb.renderer_path)[1]
    return BenchSetup(
        name=str(root),
        proxy=np.stack([pb.proxy_vertices(t) for t in range(n)]),
        faces=pb.proxy_faces,
        uvs=pb.proxy_uvs,
        windows=np.stack([pb.joint_window(t) for t in range(n)]),
        joints=joints[:n],
        root_rotations=root_rot[:n],
        joint2coarse=pb.joint2coarse,
        camera=lambda size: pb.default_camera(0, size, size, azimuth_deg=30.0),
        background=pb.background,
        model=model,
        measures_background=True,
        stretch=pb.stretch,
    )


def time_joint2coarse(setup: BenchSetup) -> float:
    """Median ms per frame of streaming Joint2Coarse over the clip (after a warm-up)."""
    from training.joint2coarse import Joint2CoarseStream

    stream = Joint2CoarseStream(setup.joint2coarse, stretch=setup.stretch)
    for f in range(min(WARMUP, len(setup.joints))):
        stream.push(setup.joints[f], setup.root_rotations[f])
    stream.reset()
    times = []
    for f in range(len(setup.joints)):
        t0 = time.perf_counter()
        stream.push(setup.joints[f], setup.root_rotations[f])
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def time_renderer(net, setup: BenchSetup, size: int, device: str = "cpu") -> dict:
    """Median ms per frame of streaming :meth:`NeuralRenderer.render` and of its raster +
    feature part alone, over the clip after :data:`WARMUP` frames.

    Returns a dict: ``raster_feat_ms``, ``network_ms`` (the rest of the render),
    ``render_ms``, ``background_ms`` (making the background image), ``crop`` (w, h).
    """
    import torch

    from training.renderer import FrameState, NeuralRenderer

    r = NeuralRenderer(net, setup.faces, setup.uvs, device=device)
    cam = setup.camera(size)
    sync = torch.cuda.synchronize if str(device).startswith("cuda") else (lambda: None)
    total, feat, backs = [], [], []
    box = None
    for t in range(len(setup.proxy)):
        t0 = time.perf_counter()
        bg = setup.background(t, cam)
        t1 = time.perf_counter()
        frame = FrameState(setup.proxy[t], setup.windows[t], bg)
        r.render(cam, frame)
        sync()
        t2 = time.perf_counter()
        # raster + features alone, on a fresh scene (as render does for each new frame)
        box = r.crop_box(cam, frame)
        crop = crop_camera(cam, box.x0, box.y0, box.width, box.height)
        fresh = FrameState(frame.vertices.copy(), frame.window, bg)
        t3 = time.perf_counter()
        with torch.no_grad():
            r.features(r._frame_data(fresh), crop)
        sync()
        t4 = time.perf_counter()
        if t >= WARMUP or len(setup.proxy) <= WARMUP:
            backs.append(t1 - t0)
            total.append(t2 - t1)
            feat.append(t4 - t3)
    ms, fm = 1e3 * float(np.median(total)), 1e3 * float(np.median(feat))
    return {
        "raster_feat_ms": fm,
        "network_ms": ms - fm,
        "render_ms": ms,
        "background_ms": 1e3 * float(np.median(backs)),
        "crop": [box.width, box.height],
    }


def measure(
    setup: BenchSetup,
    presets: list[str],
    sizes: list[int],
    threads: list[int],
    device: str = "cpu",
    report=None,
) -> list[dict]:
    """One row per (preset, size, threads): ms per part, fps, target and load average.

    ``presets`` names :data:`training.renderer.PRESETS` (random weights) or ``project``
    (the setup's trained model). ``report(row)`` is called as each row is done.
    """
    import torch

    from training.renderer import PRESETS, RenderNet

    rows = []
    dev_type = "cuda" if str(device).startswith("cuda") else "cpu"
    for name in presets:
        if name == "project" and setup.model is None:
            raise InputError("preset 'project' needs --project with a trained renderer")
        if name != "project" and name not in PRESETS:
            raise InputError(f"unknown preset {name!r}; choose from project, {', '.join(PRESETS)}")
        for size in sizes:
            for n_threads in threads:
                torch.set_num_threads(n_threads)
                j2c_ms = time_joint2coarse(setup)
                torch.manual_seed(0)
                net = setup.model if name == "project" else RenderNet(PRESETS[name])
                timing = time_renderer(net, setup, size, device)
                frame_ms = j2c_ms + timing["render_ms"]
                target = TARGETS_FPS.get((dev_type, name, size))
                if target is None and name == "project":
                    cfg = setup.model.config
                    kind = "paper" if cfg.max_width >= 512 else "cpu"
                    target = TARGETS_FPS.get((dev_type, kind, size))
                fps = 1e3 / frame_ms
                row = {
                    "setup": setup.name,
                    "preset": name,
                    "size": size,
                    "threads": n_threads,
                    "device": str(device),
                    "frames": len(setup.proxy) - WARMUP,
                    "crop": timing["crop"],
                    "joint2coarse_ms": j2c_ms,
                    "raster_feat_ms": timing["raster_feat_ms"],
                    "network_ms": timing["network_ms"],
                    "frame_ms": frame_ms,
                    "fps": fps,
                    "target_fps": target,
                    "meets_target": None if target is None else bool(fps >= target),
                    "background_ms": timing["background_ms"] if setup.measures_background else None,
                    "fps_with_background": 1e3 / (frame_ms + timing["background_ms"])
                    if setup.measures_background
                    else None,
                    "load_average": os.getloadavg()[0],
                    "path": "numpy",
                    "batch": 1,
                    "batch_fps": None,
                    "device_name": device_name(device),
                    "torch": torch.__version__,
                }
                rows.append(row)
                if report is not None:
                    report(row)
    return rows


def device_name(device) -> str:
    """The GPU's name, or the CPU's model and core count."""
    import torch

    if str(device).startswith("cuda"):
        return torch.cuda.get_device_name(torch.device(device))
    model = ""
    try:
        with open("/proc/cpuinfo") as f:
            model = next(
                (ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), ""
            )
    except OSError:
        pass
    return f"{model or 'CPU'} ({os.cpu_count()} cores)"


def synthetic_bundle(frames: int, resolution: int = 64) -> dict:
    """A torch bundle of the synthetic skirt (no body: a flat background), for the torch path
    without a project. Joint2Coarse has random weights and output statistics that put the skirt
    at the synthetic walk's root (its mean is the skirt, its spread a millimetre), so it costs
    what a trained one costs and its proxy stays a skirt in view."""
    import torch

    from training.joint2coarse import Joint2CoarseConfig, joint2coarse_inputs
    from training.joint2coarse.descriptor import heading_rotations, to_root_frame
    from training.joint2coarse.model import MODEL_FORMAT, Joint2CoarseNet
    from training.joint2coarse.synthetic import synthetic_walk
    from training.renderer import RenderNet, synthetic_scene
    from training.renderer.config import RendererConfig
    from training.torchpath import BUNDLE_FORMAT

    scene = synthetic_scene(frames, resolution=resolution, seed=0)
    motion = synthetic_walk(frames, seed=0)
    joints, root_rot = joint2coarse_inputs(motion)
    config = Joint2CoarseConfig()
    torch.manual_seed(0)
    n = scene.proxy.shape[1]
    net = Joint2CoarseNet(config, n, config.num_samples * 57).eval()
    local = to_root_frame(scene.proxy[:1], joints[:1, 0], heading_rotations(root_rot[:1]))
    net.set_statistics(
        net.desc_mean, net.desc_std, local.reshape(-1), np.full(3 * n, 1e-3, np.float32)
    )
    renderer = RenderNet(RendererConfig())
    fc = FeatureConfig()
    as_t = lambda a, dt: torch.from_numpy(np.ascontiguousarray(a, dt))  # noqa: E731
    return {
        "format": BUNDLE_FORMAT,
        "joint2coarse": {
            "format": MODEL_FORMAT,
            "config": config.to_dict(),
            "n_vertices": n,
            "descriptor_dim": config.num_samples * 57,
            "state_dict": net.state_dict(),
        },
        "renderer": {"config": renderer.config.to_dict(), "generator": renderer.state_dict()},
        "proxy": {
            "faces": as_t(scene.faces, np.int64),
            "uvs": as_t(scene.uvs, np.float32),
            "seam_map": torch.arange(n),
        },
        "body": {
            "vertices": torch.zeros(0, 3),
            "weights": torch.zeros(0, 1),
            "faces": torch.zeros(0, 3, dtype=torch.long),
        },
        "rig": {"fov_y_deg": 40.0, "target_y": 0.75, "radius": 2.2},
        "features": {"sigma": fc.sigma, "frame_offsets": list(fc.frame_offsets)},
        "clips": {
            "synthetic": {
                "joints": as_t(joints, np.float32),
                "root_rotations": as_t(root_rot, np.float32),
                "root_positions": as_t(joints[:, 0], np.float64),
                "transforms": torch.eye(4).expand(frames, 1, 4, 4).clone(),
                "fps": float(motion.fps),
            }
        },
    }


def with_renderer(bundle: dict, name: str) -> dict:
    """The bundle with the renderer of ``name``: ``project`` (its own) or a preset with random
    weights (speed does not depend on the weights)."""
    import torch

    from training.renderer import PRESETS, RenderNet

    if name == "project":
        return bundle
    if name not in PRESETS:
        raise InputError(f"unknown preset {name!r}; choose from project, {', '.join(PRESETS)}")
    torch.manual_seed(0)
    net = RenderNet(PRESETS[name])
    return {**bundle, "renderer": {"config": net.config.to_dict(), "generator": net.state_dict()}}


def time_torch_path(player, camera, frames: int, batch: int) -> dict:
    """Median ms per streamed frame, end to end and by part, and batched frames per second.

    Each part is timed on its own pass over the clip: ``joint2coarse_ms``, ``background_ms``
    (posing and rendering the body), ``raster_feat_ms`` (box, proxy rasterization, UV and
    motion-feature maps, texture sample), ``network_ms`` (encoding frame t, decoding,
    pasting); ``total_ms`` is one streamed :meth:`TorchPlayer.render` (all of them),
    ``batch_fps`` frames per second of :meth:`TorchPlayer.render_batch` calls of ``batch``
    frames (background included); ``crop`` the network's window (w, h).
    """
    import torch

    from training.torchpath import TorchCamera

    dev = player.device
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    tcam = TorchCamera.from_camera(camera, dev)

    def median_ms(fn) -> float:
        times = []
        for t in range(frames):
            sync()
            t0 = time.perf_counter()
            fn(t)
            sync()
            if t >= WARMUP or frames <= WARMUP:
                times.append(time.perf_counter() - t0)
        return 1e3 * float(np.median(times))

    total = median_ms(lambda t: player.render(t, camera))
    state = {}

    def raster_feat(t):
        f = player._frames([t])
        v = state["v"][t]
        box = player._box(v, tcam)
        state["box"] = box
        if box is not None:
            state["x"] = player._inputs(f, v, tcam.crop(*box))

    def network(t):
        if state.get("box") is not None:
            z, skips = player._encode(state["x"])
            player._compose(state["bg"], state["box"], z, z, skips)

    with torch.no_grad():
        j2c = median_ms(lambda t: player.proxy([t]))
        background = median_ms(lambda t: player.background([t], tcam))
        state["v"] = [player.proxy([t]) for t in range(frames)]
        state["bg"] = player.background([0], tcam)
        feat = median_ms(raster_feat)
        net = median_ms(network)
    batch = max(1, min(batch, frames))
    starts = list(range(0, frames - batch + 1, batch)) or [0]
    player.render_batch(starts[0], batch, camera)  # warm-up
    times = []
    for s0 in starts:
        sync()
        t0 = time.perf_counter()
        player.render_batch(s0, batch, camera)
        sync()
        times.append(time.perf_counter() - t0)
    if player.window == "full":
        player.check_overflow()
    b = state.get("box") or (0, 0, 0, 0)
    return {
        "joint2coarse_ms": j2c,
        "background_ms": background,
        "raster_feat_ms": feat,
        "network_ms": net,
        "total_ms": total,
        "batch": batch,
        "batch_fps": batch / float(np.median(times)),
        "crop": [b[2], b[3]],
    }


def time_joint2coarse_torch(player, frames: int, batch: int) -> dict:
    """Joint2Coarse alone on the player's device: median ms per streamed frame (one frame per
    call: descriptor row -> world proxy, what :meth:`TorchPlayer.render` runs) and ms per frame
    in calls of ``batch`` consecutive frames."""
    import torch

    dev = player.device
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)

    def median_ms(calls) -> float:
        times = []
        for i, f in enumerate(calls):
            sync()
            t0 = time.perf_counter()
            player.proxy(f)
            sync()
            if i >= WARMUP or len(calls) <= WARMUP:
                times.append(time.perf_counter() - t0)
        return 1e3 * float(np.median(times))

    batch = max(1, min(batch, player.num_frames))
    starts = list(range(0, player.num_frames - batch + 1, batch)) or [0]
    runs = max(frames, WARMUP + 3)
    with torch.no_grad():
        one = median_ms([[t % player.num_frames] for t in range(runs)])
        many = median_ms([range(s0, s0 + batch) for s0 in (starts * runs)[:runs]])
    return {"ms": one, "batch": batch, "batch_ms": many / batch}


def joint2coarse_row(player, path: str, n_threads: int, device, timing: dict) -> dict:
    """The Joint2Coarse row of the table (its own row: it does not depend on the image)."""
    import torch

    cuda = str(device).startswith("cuda")
    return {
        "path": path,
        "model": player.joint2coarse.config.model,
        "vertices": int(player.joint2coarse.n_vertices),
        "threads": n_threads,
        "device": str(device),
        "ms_per_frame": timing["ms"],
        "batch": timing.get("batch", 1),
        "batch_ms_per_frame": timing.get("batch_ms"),
        "target_ms": TARGET_J2C_MS_CUDA if cuda else None,
        "meets_target": bool(timing["ms"] < TARGET_J2C_MS_CUDA) if cuda else None,
        "device_name": device_name(device),
        "torch": torch.__version__,
    }


def measure_torch(
    bundle: dict,
    setup_name: str,
    presets: list[str],
    sizes: list[int],
    threads: list[int],
    device: str,
    batch: int,
    frames: int,
    options: dict,
    report=None,
    j2c_rows: list | None = None,
) -> list[dict]:
    """Rows of :func:`measure`'s form for the torch path (``path`` "torch", ``batch_fps``);
    :func:`joint2coarse_row` of each thread count appended to ``j2c_rows`` when given."""
    import torch

    from training.torchpath import TorchPlayer

    rows = []
    dev_type = "cuda" if str(device).startswith("cuda") else "cpu"
    clip = next(iter(bundle["clips"]))
    if j2c_rows is not None:
        player = TorchPlayer(with_renderer(bundle, presets[0]), device, **options)
        player.set_clip(clip)
        for n_threads in threads:
            torch.set_num_threads(n_threads)
            timing = time_joint2coarse_torch(player, frames, batch)
            j2c_rows.append(joint2coarse_row(player, "torch", n_threads, device, timing))
    for name in presets:
        player = TorchPlayer(with_renderer(bundle, name), device, **options)
        player.set_clip(clip)
        n = min(frames, player.num_frames)
        kind = name
        if name == "project":
            kind = "paper" if player.config.max_width >= 512 else "cpu"
        for size in sizes:
            camera = player.camera(0, size, size, azimuth_deg=30.0)
            for n_threads in threads:
                torch.set_num_threads(n_threads)
                timing = time_torch_path(player, camera, n, batch)
                # As the numpy rows: the frame without its background (beside it, and in the
                # end-to-end figure, which times whole streamed renders).
                frame_ms = timing["joint2coarse_ms"] + timing["raster_feat_ms"]
                frame_ms += timing["network_ms"]
                target = TARGETS_FPS.get((dev_type, kind, size))
                fps = 1e3 / frame_ms
                row = {
                    "setup": setup_name,
                    "preset": name,
                    "size": size,
                    "threads": n_threads,
                    "device": str(device),
                    "frames": n - WARMUP,
                    "crop": timing["crop"],
                    "joint2coarse_ms": timing["joint2coarse_ms"],
                    "raster_feat_ms": timing["raster_feat_ms"],
                    "network_ms": timing["network_ms"],
                    "frame_ms": frame_ms,
                    "fps": fps,
                    "target_fps": target,
                    "meets_target": None if target is None else bool(fps >= target),
                    "background_ms": timing["background_ms"],
                    "fps_with_background": 1e3 / timing["total_ms"],
                    "load_average": os.getloadavg()[0],
                    "path": "torch",
                    "batch": timing["batch"],
                    "batch_fps": timing["batch_fps"],
                    "device_name": device_name(device),
                    "torch": torch.__version__,
                    "options": {k: v for k, v in options.items() if v},
                }
                if dev_type == "cuda":
                    row["joint2coarse_target_ms"] = TARGET_J2C_MS_CUDA
                rows.append(row)
                if report is not None:
                    report(row)
    return rows


HEADER = (
    f"{'path':>5} {'preset':>7} {'size':>5} {'thr':>3} {'crop':>9} {'j2c':>6} "
    f"{'raster+feat':>11} {'network':>8} {'total ms':>8} {'fps':>6} {'target':>8} "
    f"{'+bg ms':>7} {'e2e fps':>7} {'batch':>5} {'batch fps':>9} {'load':>5}  device / torch"
)


J2C_HEADER = (
    f"{'path':>5} {'Joint2Coarse':>12} {'verts':>6} {'thr':>3} {'ms/frame':>9} {'target':>9} "
    f"{'batch':>5} {'ms/frame':>9}  device / torch"
)


def format_j2c_row(r: dict) -> str:
    target = (
        ""
        if r["target_ms"] is None
        else f"{'ok' if r['meets_target'] else 'MISS'} <{r['target_ms']:g}"
    )
    batched = "" if r["batch_ms_per_frame"] is None else f"{r['batch_ms_per_frame']:.3f}"
    return (
        f"{r['path']:>5} {r['model']:>12} {r['vertices']:>6} {r['threads']:>3} "
        f"{r['ms_per_frame']:>9.3f} {target:>9} {r['batch']:>5} {batched:>9}  "
        f"{r['device_name']} / torch {r['torch']}"
    )


def format_row(r: dict) -> str:
    target = (
        ""
        if r["target_fps"] is None
        else f"{'ok' if r['meets_target'] else 'MISS'} {r['target_fps']:g}"
    )
    bg = "" if r["background_ms"] is None else f"{r['background_ms']:.1f}"
    e2e = "" if r["fps_with_background"] is None else f"{r['fps_with_background']:.1f}"
    bfps = "" if r.get("batch_fps") is None else f"{r['batch_fps']:.1f}"
    crop = f"{r['crop'][0]}x{r['crop'][1]}"
    return (
        f"{r.get('path', 'numpy'):>5} {r['preset']:>7} {r['size']:>5} {r['threads']:>3} "
        f"{crop:>9} {r['joint2coarse_ms']:>6.2f} {r['raster_feat_ms']:>11.1f} "
        f"{r['network_ms']:>8.1f} {r['frame_ms']:>8.1f} {r['fps']:>6.1f} {target:>8} {bg:>7} "
        f"{e2e:>7} {r.get('batch', 1):>5} {bfps:>9} {r['load_average']:>5.2f}  "
        f"{r.get('device_name', '')} / torch {r.get('torch', '')}"
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:

    add_output_arguments(parser)
    parser.add_argument(
        "--sizes", "--size", type=int, nargs="+", default=None, metavar="PX",
        help="image sizes (default: 128 256 512 on the numpy path, 256 512 on the torch path)",
    )  # fmt: skip
    parser.add_argument(
        "--threads", type=int, nargs="+", default=None,
        help="torch CPU threads to try (default: 1 2 on CPU, 1 on CUDA)",
    )  # fmt: skip
    parser.add_argument("--device", default="cpu", help="cpu or cuda[:i]")
    parser.add_argument(
        "--path", choices=("numpy", "torch", "both"), default=None,
        help="numpy: today's playback; torch: everything on the device (training.torchpath); "
        "default numpy on CPU, torch on CUDA",
    )  # fmt: skip
    parser.add_argument(
        "--presets", nargs="+", default=None, metavar="NAME",
        help="renderer presets with random weights (tiny, cpu, paper) or 'project' (the "
        "project's trained model); default: cpu on CPU, paper on CUDA, plus project with "
        "--project or --bundle",
    )  # fmt: skip
    parser.add_argument("--project", default=None, help="a trained project (else synthetic)")
    parser.add_argument(
        "--bundle", default=None, help="a torch bundle (dng export torch) for the torch path"
    )
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES, help="timed frames")
    parser.add_argument(
        "--batch", type=int, default=8, help="frames per call of the torch path's batched run"
    )
    parser.add_argument(
        "--resolution", type=int, default=64, help="synthetic proxy columns (64: 2k vertices)"
    )
    parser.add_argument(
        "--window", choices=("crop", "full"), default="crop",
        help="torch path: the network on the proxy's box (reads 4 numbers per frame) or on the "
        "whole image (reads nothing)",
    )  # fmt: skip
    parser.add_argument(
        "--channels-last", action="store_true", help="torch path: channels-last convolutions"
    )
    parser.add_argument("--bf16", action="store_true", help="torch path: bfloat16 autocast")


def run(args: argparse.Namespace) -> int:

    import torch

    cuda = args.device.startswith("cuda")
    if cuda and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA GPU on this machine")
    paths = {"numpy": ["numpy"], "torch": ["torch"], "both": ["numpy", "torch"]}[
        args.path or ("torch" if cuda or args.bundle else "numpy")
    ]
    sizes = args.sizes or ([256, 512] if paths == ["torch"] else [128, 256, 512])
    if args.frames < 1 or any(s < 8 for s in sizes) or args.batch < 1:
        raise InputError("--frames and --batch must be >= 1 and --sizes at least 8 pixels")
    if "numpy" in paths and args.bundle:
        raise InputError("--bundle is for the torch path: give --project for the numpy path")
    threads = args.threads or ([1] if cuda else [1, 2])
    presets = args.presets or (["paper"] if cuda else ["cpu"])
    n = args.frames + WARMUP
    say = (lambda *a: None) if args.json else print
    load_before = os.getloadavg()
    rows, j2c_rows = [], []
    name = args.bundle or args.project or "synthetic"
    say(
        f"setup {name}; device {args.device} ({device_name(args.device)}), torch "
        f"{torch.__version__}; load average {load_before[0]:.2f} (1 min), "
        f"{load_before[1]:.2f} (5 min) on {os.cpu_count()} CPUs"
    )
    say(HEADER)
    report = lambda r: say(format_row(r))  # noqa: E731
    if "numpy" in paths:
        setup = (
            project_setup(args.project, n) if args.project else synthetic_setup(n, args.resolution)
        )
        use = presets
        if args.project and args.presets is None and setup.model is not None:
            use = ["project", *presets]
        rows += measure(setup, use, sizes, threads, args.device, report=report)
        for n_threads in threads:  # as measured beside the first preset's rows
            first = next(r for r in rows if r["path"] == "numpy" and r["threads"] == n_threads)
            j2c_rows.append(
                joint2coarse_row(
                    setup, "numpy", n_threads, args.device, {"ms": first["joint2coarse_ms"]}
                )
            )
    if "torch" in paths:
        if args.bundle:
            from training.torchpath import load_bundle

            bundle = load_bundle(args.bundle)
        elif args.project:
            from pipeline.torch_export import make_bundle

            bundle = make_bundle(args.project)
        else:
            bundle = synthetic_bundle(n, args.resolution)
        use = presets
        if (args.project or args.bundle) and args.presets is None:
            use = ["project", *presets]
        options = {"window": args.window, "channels_last": args.channels_last, "bf16": args.bf16}
        rows += measure_torch(
            bundle, name, use, sizes, threads, args.device, args.batch, n, options, report,
            j2c_rows,
        )  # fmt: skip
    say("")
    say(J2C_HEADER)
    for r in j2c_rows:
        say(format_j2c_row(r))
    table = {
        "bench": "render",
        "setup": name,
        "device": args.device,
        "device_name": device_name(args.device),
        "torch": torch.__version__,
        "load_average_before": list(load_before),
        "load_average_after": list(os.getloadavg()),
        "targets_fps": {f"{d}/{p}/{s}": v for (d, p, s), v in TARGETS_FPS.items()},
        "target_joint2coarse_ms_cuda": TARGET_J2C_MS_CUDA,
        "rows": rows,
        "joint2coarse_rows": j2c_rows,
    }
    out = Path(args.out)
    write_json(out / "render.json", table)
    wrote = [out / "render.json"]
    try:
        import matplotlib  # noqa: F401  (a torch-only machine has none: the table is enough)
    except ImportError:
        say("no matplotlib here: plot skipped")
    else:
        plot(rows, out / "render.png")
        wrote.append(out / "render.png")
    if args.json:
        print(json.dumps(table, indent=2))
    else:
        print(f"load average after: {os.getloadavg()[0]:.2f}")
        print(f"wrote {' and '.join(map(str, wrote))}")
    return 0


def plot(rows: list[dict], path) -> None:
    """Stacked ms per part for each row, with each row's target frame time as a tick."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [f"{r.get('path', '')} {r['preset']}\n{r['size']}px t{r['threads']}" for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(5, 1.1 * len(rows) + 2), 4))
    bottom = np.zeros(len(rows))
    for key, name in (
        ("joint2coarse_ms", "Joint2Coarse"),
        ("raster_feat_ms", "raster + features"),
        ("network_ms", "network"),
    ):
        vals = np.array([r[key] for r in rows])
        ax.bar(x, vals, bottom=bottom, label=name)
        bottom += vals
    for i, r in enumerate(rows):
        if r["target_fps"]:
            ax.plot([i - 0.4, i + 0.4], [1e3 / r["target_fps"]] * 2, "k--", lw=1)
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_ylabel("ms per frame (dashed: target)")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    ax.set_title(f"Neural rendering per frame ({rows[0]['device'] if rows else ''})")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
