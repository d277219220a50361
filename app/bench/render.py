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

Targets: >= 10 fps at 128 px and >= 3 fps at 256 px on 2 CPU cores (the ``cpu`` preset);
>= 100 fps at 512 px on a GPU (``--device cuda``, the ``paper`` preset).
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass

import numpy as np

HELP = "neural rendering: Joint2Coarse + raster/features + network ms per frame vs fps targets"

#: (device type, preset, size) -> frames per second to reach.
TARGETS_FPS = {("cpu", "cpu", 128): 10.0, ("cpu", "cpu", 256): 3.0, ("cuda", "paper", 512): 100.0}
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


def synthetic_setup(frames: int, resolution: int = 64) -> BenchSetup:
    """The synthetic skirt (``resolution`` columns: about 2k vertices at 64) over a flat grey."""
    import torch

    from core.camera import make_camera
    from core.features import joint_window
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
    from training.playback import Playback, load_motion_for

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
    )


def time_joint2coarse(setup: BenchSetup) -> float:
    """Median ms per frame of streaming Joint2Coarse over the clip (after a warm-up)."""
    from training.joint2coarse import Joint2CoarseStream

    stream = Joint2CoarseStream(setup.joint2coarse)
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

    from core.camera import crop_camera
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

    from core.errors import InputError
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
                }
                rows.append(row)
                if report is not None:
                    report(row)
    return rows


HEADER = (
    f"{'preset':>7} {'size':>5} {'thr':>3} {'crop':>9} {'j2c':>6} {'raster+feat':>11} "
    f"{'network':>8} {'total ms':>8} {'fps':>6} {'target':>7} {'+bg ms':>7} {'load':>5}"
)


def format_row(r: dict) -> str:
    target = (
        ""
        if r["target_fps"] is None
        else f"{'ok' if r['meets_target'] else 'MISS'} {r['target_fps']:g}"
    )
    bg = "" if r["background_ms"] is None else f"{r['background_ms']:.1f}"
    crop = f"{r['crop'][0]}x{r['crop'][1]}"
    return (
        f"{r['preset']:>7} {r['size']:>5} {r['threads']:>3} {crop:>9} {r['joint2coarse_ms']:>6.2f} "
        f"{r['raster_feat_ms']:>11.1f} {r['network_ms']:>8.1f} {r['frame_ms']:>8.1f} "
        f"{r['fps']:>6.1f} {target:>7} {bg:>7} {r['load_average']:>5.2f}"
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from app.bench import add_output_arguments

    add_output_arguments(parser)
    parser.add_argument("--sizes", type=int, nargs="+", default=[128, 256, 512], metavar="PX")
    parser.add_argument(
        "--threads", type=int, nargs="+", default=None,
        help="torch CPU threads to try (default: 1 2 on CPU, 1 on CUDA)",
    )  # fmt: skip
    parser.add_argument("--device", default="cpu", help="cpu or cuda[:i]")
    parser.add_argument(
        "--presets", nargs="+", default=None, metavar="NAME",
        help="renderer presets with random weights (tiny, cpu, paper) or 'project' (the "
        "project's trained model); default: cpu on CPU, paper on CUDA, plus project with "
        "--project",
    )  # fmt: skip
    parser.add_argument("--project", default=None, help="a trained project (else synthetic)")
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES, help="timed frames")
    parser.add_argument(
        "--resolution", type=int, default=64, help="synthetic proxy columns (64: 2k vertices)"
    )


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    import torch

    from core.errors import InputError
    from core.fileio import write_json

    cuda = args.device.startswith("cuda")
    if cuda and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA GPU on this machine")
    if args.frames < 1 or any(s < 8 for s in args.sizes):
        raise InputError("--frames must be >= 1 and --sizes at least 8 pixels")
    threads = args.threads or ([1] if cuda else [1, 2])
    presets = args.presets or (["paper"] if cuda else ["cpu"])
    n = args.frames + WARMUP
    setup = project_setup(args.project, n) if args.project else synthetic_setup(n, args.resolution)
    if args.project and args.presets is None and setup.model is not None:
        presets = ["project", *presets]
    load_before = os.getloadavg()
    say = (lambda *a: None) if args.json else print
    say(
        f"setup {setup.name}: proxy {setup.proxy.shape[1]} vertices, {len(setup.faces)} faces; "
        f"device {args.device}; load average {load_before[0]:.2f} (1 min), "
        f"{load_before[1]:.2f} (5 min) on {os.cpu_count()} CPUs"
    )
    say(HEADER)
    rows = measure(
        setup, presets, args.sizes, threads, args.device, report=lambda r: say(format_row(r))
    )
    table = {
        "bench": "render",
        "setup": setup.name,
        "device": args.device,
        "device_name": torch.cuda.get_device_name(0) if cuda else f"{os.cpu_count()} CPUs",
        "load_average_before": list(load_before),
        "load_average_after": list(os.getloadavg()),
        "targets_fps": {f"{d}/{p}/{s}": v for (d, p, s), v in TARGETS_FPS.items()},
        "rows": rows,
    }
    out = Path(args.out)
    write_json(out / "render.json", table)
    plot(rows, out / "render.png")
    if args.json:
        print(json.dumps(table, indent=2))
    else:
        print(f"load average after: {os.getloadavg()[0]:.2f}")
        print(f"wrote {out / 'render.json'} and {out / 'render.png'}")
    return 0


def plot(rows: list[dict], path) -> None:
    """Stacked ms per part for each row, with each row's target frame time as a tick."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from core.fileio import atomic_path

    labels = [f"{r['preset']}\n{r['size']}px t{r['threads']}" for r in rows]
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
