"""``dng bench trade``: the speed/accuracy trade a user makes on a trained project.

Four measurements, on the machine it runs on, in one run:

1. **Resolution x network width.** For each render resolution (``--sizes``) and each renderer
   width (``--widths`` as ``BASE/MAX``: the encoder's first and latent channels, the rest of
   the project's renderer preset unchanged), a renderer is trained from scratch for
   ``--steps`` steps on the project's data set, then measured: ms per frame of live playback
   (Joint2Coarse streaming + raster/features + network on the crop, the timing code of
   :mod:`app.bench.render` on the project's training motion and its default camera) and image
   quality on a test motion from unseen cameras (:func:`training.evaluate.evaluate_motion`
   with Joint2Coarse's proxy, as at test time). Quality is given twice: ``psnr`` etc. at the
   project's resolution (the low-resolution render upsampled bilinearly to it and compared
   with the full-resolution ground truth: what the user sees at display size, comparable
   across resolutions) and ``psnr_native`` (against the ground truth area-downsampled to the
   render's own resolution). **Limitation:** lower resolutions are made from the project's
   data set (cameras rescaled with :func:`core.camera.resize_camera` for the UV and
   motion-feature maps, ground-truth images, backgrounds and masks area-downsampled), so only
   resolutions at or below the project's image size can be measured: nothing is upsampled,
   there is no ground truth above it. Every renderer trains the same number of steps; a wider
   network would gain more from a longer run than this bench gives it.
2. **Proxy size** (``--proxy-sizes``): proxies of other vertex budgets derived from the
   project's detailed target (:func:`core.proxy.derive_proxy`), with Joint2Coarse streaming
   (a network of the project's Joint2Coarse configuration sized for that proxy, random weights:
   speed does not depend on them) and raster + features (the proxy at rest, the motion's
   joints) per frame. **Speed only**: no renderer is trained per proxy size. The accuracy
   column is the proxy's geometric Hausdorff distance to the target at rest (from the proxy
   report, relative to the target's bounding-box diagonal), not image quality.
3. **Neural against simulation.** ms per frame of Joint2Coarse streaming + neural render
   (:class:`pipeline.playback.Playback` on the test motion at the project's image size) against
   newton cloth simulation (:func:`core.sim.simulate.simulate`) of the detailed target
   (``garment/target.obj``) on the first ``--sim-frames`` frames of the same motion with the
   project's fabric and substeps (when that blows up, as a layered target can at a proxy's
   substeps, the failure is reported and the clip simulated again at the ``final`` quality,
   8 substeps x 16 iterations); the ratio is simulation ms / neural ms. The paper's: about
   32x (16 fps against 0.5 fps). Simulation ms counts clip frames only (not the lead-in from the
   rest pose, shortened to ``--sim-lead-in`` seconds here, nor kernel compilation); neither side
   counts the body-only background (reported beside the neural time) nor shading the simulated
   mesh into an image.
4. **Memory.** Every training, every inference measurement, the proxy axis and the simulation
   run in their own spawned process; each reports its peak resident set size
   (``ru_maxrss``, MiB, which includes the interpreter and the libraries it imported) and, on
   CUDA, ``torch.cuda.max_memory_allocated``. Inference peaks are read after the timed
   playback, before the quality evaluation.

Writes ``OUT/trade.json``, ``OUT/trade.png`` (ms/frame against PSNR, each point labelled, the
Pareto front drawn) and the trained renderers under ``OUT/runs/`` (never into the project).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing
import os
import resource
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from app.bench import add_output_arguments, project_test_sets
from app.bench.render import DEFAULT_FRAMES, WARMUP, project_setup, time_joint2coarse, time_renderer
from core.camera import resize_camera
from core.errors import InputError
from core.fileio import atomic_path, write_json
from core.mesh import load_mesh
from core.project import Project
from core.proxy import ProxyConfig, derive_proxy
from core.sim import SimConfig
from core.sim.config import QUALITY
from pipeline.config import project_config, renderer_config
from pipeline.playback import Playback, load_motion_for
from training.dataset import GarmentDataset, proxy_source_file

HELP = "speed vs accuracy on a trained project: resolution x width, proxy size, neural vs sim"

#: Renderer training steps per setting.
DEFAULT_STEPS = 300
#: Proxy vertex budgets of the proxy-size axis.
DEFAULT_PROXY_SIZES = (300, 1000, 2000)
#: Clip frames simulated for the neural-against-simulation comparison.
DEFAULT_SIM_FRAMES = 10
#: Lead-in of that simulation (seconds blending from the rest pose, seconds holding frame 0):
#: shorter than the project's (not timed; it only has to reach the clip without blowing up).
DEFAULT_SIM_LEAD_IN = (0.3, 0.1)
#: The paper's ratio of simulation to neural time per frame (16 fps against 0.5 fps).
PAPER_RATIO = 32.0


def add_arguments(parser: argparse.ArgumentParser) -> None:

    add_output_arguments(parser)
    parser.add_argument("--project", required=True, help="a trained project folder (dng demo)")
    parser.add_argument(
        "--steps", type=int, default=DEFAULT_STEPS,
        help="renderer training steps per setting (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--sizes", type=int, nargs="+", default=None, metavar="PX",
        help="render resolutions, at most the project's image size (default: it and its half)",
    )  # fmt: skip
    parser.add_argument(
        "--widths", nargs="+", default=None, metavar="BASE/MAX",
        help="renderer widths (encoder's first layer / latent channels); default: half, equal "
        "and double the project's preset (cpu: 8/64 16/128 32/256)",
    )  # fmt: skip
    parser.add_argument(
        "--motion", default=None,
        help="test motion for quality and the simulation comparison (default: the first with "
        "a test set)",
    )  # fmt: skip
    parser.add_argument(
        "--proxy-sizes", type=int, nargs="*", default=list(DEFAULT_PROXY_SIZES), metavar="N",
        help="proxy vertex budgets of the speed-only proxy axis; none to skip "
        "(default: %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--sim-frames", type=int, default=DEFAULT_SIM_FRAMES,
        help="frames simulated against the neural render; 0 skips (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--sim-lead-in", type=float, nargs=2, default=list(DEFAULT_SIM_LEAD_IN),
        metavar=("BLEND_S", "HOLD_S"), help="simulation lead-in (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES, help="timed frames")
    parser.add_argument("--device", default="cpu", help="cpu or cuda[:i] (training, rendering)")
    parser.add_argument(
        "--threads", type=int, default=1, help="torch CPU threads in each process (default: 1)"
    )


# ------------------------------------------------------------------------- lower resolutions


def area_downsample(images, size: tuple[int, int]):
    """``(..., C, H, W)`` float tensor -> ``(..., C, h, w)`` by area averaging (box filter)."""
    import torch
    from torch.nn import functional as F

    lead = images.shape[:-3]
    flat = images.reshape(-1, *images.shape[-3:])
    if tuple(flat.shape[-2:]) != tuple(size):
        flat = F.interpolate(flat, size=size, mode="area")
    return torch.as_tensor(flat).reshape(*lead, *flat.shape[-3:])


class ResizedDataset:
    """A :class:`training.dataset.GarmentDataset` seen at a lower resolution.

    Each item is the base sample with its UV, motion-feature, proxy-mask and proxy-shading
    maps rasterized anew from the camera rescaled to ``size`` pixels wide
    (:func:`core.camera.resize_camera`), and its ground-truth image, background and garment mask
    area-downsampled. Only downsampling: ``size`` above the data set's resolution is refused.

    Parameters
    ----------
    base : GarmentDataset
    size : int, the new width in pixels (the height keeps the aspect ratio)
    keep_full : bool
        False: the item's keys hold the low-resolution sample. True: they hold the base
        (full-resolution) sample, and ``lo_KEY`` the low-resolution one, for
        :class:`UpsampledRenderer` (render low, score at full resolution).
    """

    def __init__(self, base, size: int, keep_full: bool = False):

        width = base.samples[0][2].width if len(base) else size
        if size > width:
            raise InputError(
                f"render size {size} px is above the data set's {width} px: this bench only "
                "downsamples",
                base.folder,
            )
        self.base = base
        self.size = int(size)
        self.keep_full = keep_full

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, i: int) -> dict:
        import torch

        full = self.base[i]
        t, _, camera = self.base.samples[i]
        h = max(1, round(camera.height * self.size / camera.width))
        if (self.size, h) == (camera.width, camera.height):
            low = dict(full)
        else:
            small = resize_camera(camera, self.size, h)
            frames = [self.base.proxy_maps(f, small) for f in (t - 1, t, t + 1)]
            low = {
                k: torch.from_numpy(np.ascontiguousarray(np.stack([fr[k] for fr in frames]), np.float32))
                for k in frames[0]
            }  # fmt: skip
            for key in ("target", "background", "target_mask"):
                low[key] = area_downsample(full[key], (h, self.size))
        if not self.keep_full:
            return low
        return {**full, **{f"lo_{k}": v for k, v in low.items()}}


class UpsampledRenderer:
    """Renders the ``lo_*`` inputs of a :class:`ResizedDataset` (``keep_full=True``) batch and
    upsamples the result bilinearly to the batch's full resolution: ``render(batch) ->
    (B, 3, H, W)``, what :func:`training.evaluate.evaluate_motion` scores."""

    def __init__(self, net):
        from training.baselines.common import RendererAdapter

        self.adapter = RendererAdapter(net)

    def render(self, batch: dict):
        from torch.nn import functional as F

        low = {k[3:]: v for k, v in batch.items() if k.startswith("lo_")}
        rgb = self.adapter.render(low)
        size = tuple(batch["target"].shape[-2:])
        if tuple(rgb.shape[-2:]) != size:
            rgb = F.interpolate(rgb.float(), size=size, mode="bilinear", align_corners=False)
        return rgb


# ------------------------------------------------------------------------- settings


def parse_widths(texts: list[str]) -> list[tuple[int, int]]:
    """``["8/64", ...]`` -> ``[(8, 64), ...]``; InputError on anything else."""
    out = []
    for text in texts:
        try:
            base, top = (int(x) for x in str(text).split("/"))
        except ValueError:
            raise InputError(f"bad width {text!r}: use BASE/MAX, e.g. 16/128") from None
        if base < 1 or top < base:
            raise InputError(f"bad width {text!r}: need 1 <= BASE <= MAX")
        out.append((base, top))
    return out


def default_widths(cfg) -> list[tuple[int, int]]:
    """Half, equal and double the preset's (base_width, max_width)."""
    b, m = cfg.base_width, cfg.max_width
    return [(max(1, b // 2), max(1, m // 2)), (b, m), (2 * b, 2 * m)]


def check_project(root: Path, motion: str | None) -> tuple[object, str]:
    """The project's pipeline settings and the test motion to use; InputError naming what is
    missing (the folder, its data set, test set or Joint2Coarse)."""
    if not root.is_dir():
        raise InputError("project folder not found", root)
    config = project_config(Project(root))
    for rel, what in (
        ("dataset/samples.json", "no data set: run dng dataset (or dng demo) first"),
        ("joint2coarse/joint2coarse.pt", "no trained Joint2Coarse: run dng train joint2coarse"),
    ):
        if not (root / rel).is_file():
            raise InputError(what, root / rel)
    order = project_test_sets(root, config)
    if motion is None:
        motion = order[0]
    elif motion not in order:
        raise InputError(
            f"no test set for motion {motion!r}; have {', '.join(sorted(order))}", root / "testset"
        )
    pred = proxy_source_file(root, "joint2coarse", motion)
    if not pred.is_file():
        raise InputError(f"no Joint2Coarse prediction of {motion}", pred)
    return config, motion


def setting_config(config, size: int, widths: tuple[int, int], steps: int):
    """The project's renderer configuration at ``size`` px with other widths and a step budget
    (no previews; one checkpoint at the end)."""
    return renderer_config(config).replace(
        image_size=int(size), base_width=widths[0], max_width=widths[1], steps=int(steps),
        preview_every=0, checkpoint_every=max(int(steps), 1),
    )  # fmt: skip


# ------------------------------------------------------------------------- child processes


def _child(name: str, kwargs: dict, threads: int, device: str) -> dict:
    """Run ``name(**kwargs)`` of this module and add the process's memory peaks."""

    import torch

    torch.set_num_threads(threads)
    cuda = str(device).startswith("cuda")
    if cuda:
        torch.cuda.reset_peak_memory_stats()
    start_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    result = globals()[name](**kwargs)
    result.setdefault("peak_rss_mib", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    result["rss_at_start_mib"] = start_mib
    if cuda:
        result.setdefault("cuda_peak_mib", torch.cuda.max_memory_allocated() / 2**20)
    return result


def spawned(name: str, threads: int, device: str, **kwargs) -> dict:
    """``name(**kwargs)`` in a fresh spawned process (its own memory peak): its result dict,
    with ``peak_rss_mib``, ``rss_at_start_mib`` and on CUDA ``cuda_peak_mib``."""
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        return pool.submit(_child, name, {**kwargs, "device": device}, threads, device).result()


def _rss_now() -> float:

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def train_setting(project: str, size: int, widths: tuple, steps: int, out_dir: str,
                  device: str) -> dict:  # fmt: skip
    """Train one setting's renderer into ``out_dir`` (from scratch)."""

    from training.renderer.train import train_renderer

    config = project_config(Project(project))
    cfg = setting_config(config, size, tuple(widths), steps)
    shutil.rmtree(out_dir, ignore_errors=True)  # time a fresh run, never a resumed one
    data = GarmentDataset(project, source=config.renderer_source)
    data = ResizedDataset(data, size)
    start = time.perf_counter()
    result = train_renderer(data, out_dir, cfg, device=device, progress=False)
    seconds = time.perf_counter() - start
    return {
        "model": str(result.model_path),
        "train_seconds": seconds,
        "seconds_per_step": seconds / max(steps, 1),
        "skipped_steps": result.skipped_steps,
        "parameters": sum(p.numel() for p in result.net.parameters()),
    }


def infer_setting(project: str, model: str, size: int, frames: int, motion: str,
                  device: str) -> dict:  # fmt: skip
    """Time live playback of one renderer (then read the memory peak), then score it."""
    import torch

    from training.baselines.common import RendererAdapter
    from training.evaluate import EvalConfig, evaluate_motion
    from training.renderer.train import load_model

    net = load_model(model)[1].to(device)
    setup = project_setup(project, frames + WARMUP)
    j2c_ms = time_joint2coarse(setup)
    timing = time_renderer(net, setup, size, device)
    out = {
        "joint2coarse_ms": j2c_ms,
        **timing,
        "frame_ms": j2c_ms + timing["render_ms"],
        "timed_frames": len(setup.proxy) - WARMUP,
        "peak_rss_mib": _rss_now(),
    }
    if str(device).startswith("cuda"):
        out["cuda_peak_mib"] = torch.cuda.max_memory_allocated() / 2**20
    data = GarmentDataset(project, source="joint2coarse", split=motion)
    full_size = data.samples[0][2].width
    methods = {"native": (RendererAdapter(net), ResizedDataset(data, size))}
    if size != full_size:
        methods["full"] = (UpsampledRenderer(net), ResizedDataset(data, size, keep_full=True))
    results, _ = evaluate_motion(methods, EvalConfig(sheet_samples=0))
    out["quality_native"] = results["native"].metrics.summary()
    out["quality"] = results["full" if "full" in results else "native"].metrics.summary()
    out["test_samples"] = len(data)
    out["full_size"] = full_size
    return out


def proxy_axis(project: str, sizes: list, frames: int, device: str) -> dict:
    """Joint2Coarse streaming + raster/features ms per frame for proxies of other sizes:
    ``{"rows": [...]}``."""

    import torch

    from training.joint2coarse.model import Joint2CoarseNet
    from training.renderer import RenderNet

    config = project_config(Project(project))
    setup = project_setup(project, frames + WARMUP)
    j2c = setup.joint2coarse
    target, _ = load_mesh(Path(project) / "garment" / "target.obj")
    torch.manual_seed(0)
    net = RenderNet(renderer_config(config))  # random weights: the network's speed only
    rows = []
    for n in sizes:
        start = time.perf_counter()
        result = derive_proxy(
            target, ProxyConfig(target_verts=n, texture_size=config.proxy_texture)
        )
        derive_s = time.perf_counter() - start
        vs = result.positions.num_vertices
        torch.manual_seed(0)
        model = Joint2CoarseNet(j2c.config, vs, j2c.descriptor_dim).eval()
        proxy = np.repeat(result.proxy.vertices[None].astype(np.float32), len(setup.proxy), 0)
        s = replace(setup, proxy=proxy, faces=result.proxy.faces, uvs=result.proxy.uvs,
                    joint2coarse=model)  # fmt: skip
        j2c_ms = time_joint2coarse(s)
        timing = time_renderer(net, s, config.image_size, device)
        dist = result.report["distance"]
        rows.append({
            "target_verts": n,
            "vertices": vs,
            "uv_vertices": result.proxy.num_vertices,
            "faces": len(result.proxy.faces),
            "derive_s": derive_s,
            "joint2coarse_ms": j2c_ms,
            "raster_feat_ms": timing["raster_feat_ms"],
            "network_ms": timing["network_ms"],
            "frame_ms": j2c_ms + timing["raster_feat_ms"],
            "hausdorff_m": dist["hausdorff_m"],
            "hausdorff_rel": dist["hausdorff_rel"],
            "size": config.image_size,
        })  # fmt: skip
    return {"rows": rows}


def neural_playback(project: str, model: str, motion: str, frames: int, device: str) -> dict:
    """Joint2Coarse streaming + neural render of the test motion through :class:`Playback`."""

    from training.joint2coarse import joint2coarse_inputs

    pb = Playback(project, device=device, renderer_path=model)
    clip = load_motion_for(pb.project, motion)
    n = min(frames + WARMUP, clip.num_frames)
    clip = load_motion_for(pb.project, motion, frames=n)
    pb.set_motion(clip)
    size = pb.config.image_size
    camera = pb.default_camera(0, size, size, azimuth_deg=30.0)
    parts = {"raster+network": [], "background": []}
    for t in range(n):
        pb.render(t, camera)
        if t >= WARMUP or n <= WARMUP:
            for k in parts:
                parts[k].append(pb.last_timings[k])
    joints, root_rot = joint2coarse_inputs(clip)
    j2c_ms = time_joint2coarse(SimpleNamespace(joint2coarse=pb.joint2coarse, joints=joints,
                                               root_rotations=root_rot))  # fmt: skip
    render_ms = float(np.median(parts["raster+network"]))
    return {
        "motion": motion,
        "size": size,
        "frames": len(parts["background"]),
        "model": str(model),
        "joint2coarse_ms": j2c_ms,
        "joint2coarse_batch_ms": pb.joint2coarse_ms,
        "render_ms": render_ms,
        "background_ms": float(np.median(parts["background"])),
        "frame_ms": j2c_ms + render_ms,
    }


def simulate_target(
    project: str, motion: str, frames: int, lead_in: tuple, device: str = "cpu"
) -> dict:
    """newton simulation of the detailed target on the first ``frames`` frames of ``motion``
    with the project's fabric and substeps (solver iterations: the :class:`SimConfig` default).

    When that blows up (a layered target often does at a proxy's substeps: it is why the
    ``quick`` preset embeds the target instead), the failure is kept in ``attempts`` and the
    clip is simulated again at :data:`core.sim.config.QUALITY` ``final``; ``setting`` says which
    one the reported ``ms_per_frame`` comes from.
    """

    from core.sim.simulate import simulate

    project_obj = Project(project)
    config = project_config(project_obj)
    target_file = Path(project) / "garment" / "target.obj"
    garment, _ = load_mesh(target_file)
    clip = load_motion_for(project_obj, motion)
    clip = load_motion_for(project_obj, motion, frames=min(frames, clip.num_frames))
    cfg = SimConfig(
        fabric=config.fabric, substeps=config.sim_substeps, iterations=config.sim_iterations,
        transition_s=float(lead_in[0]), settle_s=float(lead_in[1]),
        device="cuda" if str(device).startswith("cuda") else "cpu",
    )  # fmt: skip
    substeps, iterations = QUALITY["final"]
    tries = [("project", cfg)]
    if (cfg.substeps, cfg.iterations) != (substeps, iterations):
        tries.append(("final", replace(cfg, substeps=substeps, iterations=iterations)))
    out = {
        "motion": motion,
        "frames": clip.num_frames,
        "vertices": garment.num_vertices,
        "project_target_mode": config.target_mode,
        "attempts": [],
    }
    for name, c in tries:
        attempt = {"setting": name, "fabric": c.fabric, "solver": c.solver,
                   "substeps": c.substeps, "iterations": c.iterations,
                   "lead_in_s": [c.transition_s, c.settle_s], "device": c.device}  # fmt: skip
        out["attempts"].append(attempt)
        start = time.perf_counter()
        try:
            with contextlib.redirect_stdout(sys.stderr):
                _, report = simulate(garment, clip, config.body, c, path=target_file)
        except Exception as exc:  # noqa: BLE001 - a blow-up is a result to report, not a crash
            attempt["error"] = f"{type(exc).__name__}: {exc}"
            attempt["wall_s"] = time.perf_counter() - start
            continue
        attempt.update(
            ms_per_frame=report.ms_per_frame, setup_s=report.setup_s, wall_s=report.wall_s,
            steps_per_frame=report.steps_per_frame, retried_frames=list(report.retried_frames),
            strain_max=report.strain_max,
        )  # fmt: skip
        out.update(attempt)
        return out
    out["error"] = "; ".join(f"{a['setting']}: {a['error']}" for a in out["attempts"])
    return out


# ------------------------------------------------------------------------- the bench


def _metric(summary: dict, name: str):
    m = summary.get(name) or {}
    return m.get("mean")


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points (ms, quality) no other point beats on both (less ms, more
    quality), sorted by ms."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], -points[i][1]))
    front, best = [], -np.inf
    for i in order:
        if points[i][1] > best:
            front.append(i)
            best = points[i][1]
    return front


HEADER = (
    f"{'size':>5} {'width':>7} {'params':>8} {'s/step':>7} {'train MiB':>9} {'ms/frame':>8} "
    f"{'fps':>6} {'PSNR':>6} {'SSIM':>6} {'MSE':>8} {'PSNRm':>6} {'PSNRnat':>7} {'inf MiB':>7}"
)


def _fmt(v, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def format_row(r: dict) -> str:
    return (
        f"{r['size']:>5} {r['label'].split()[1]:>7} {r['parameters']:>8} "
        f"{r['seconds_per_step']:>7.2f} {r['train_peak_rss_mib']:>9.0f} {r['frame_ms']:>8.1f} "
        f"{r['fps']:>6.1f} {_fmt(r['psnr'], '6.2f')} {_fmt(r['ssim'], '6.3f')} "
        f"{_fmt(r['mse'], '8.5f')} {_fmt(r['psnr_masked'], '6.2f')} "
        f"{_fmt(r['psnr_native'], '7.2f')} {r['infer_peak_rss_mib']:>7.0f}"
    )


def run(args: argparse.Namespace) -> int:

    root = Path(args.project)
    config, motion = check_project(root, args.motion)
    preset_cfg = renderer_config(config)
    full = config.image_size
    sizes = args.sizes or sorted({full, full // 2}, reverse=True)
    widths = parse_widths(args.widths) if args.widths else default_widths(preset_cfg)
    if args.steps < 1 or args.frames < 1 or args.sim_frames < 0 or args.threads < 1:
        raise InputError("--steps, --frames and --threads must be >= 1, --sim-frames >= 0")
    for s in sizes:
        if s > full:
            raise InputError(
                f"--sizes {s}: above the project's image size {full} px (this bench only "
                "downsamples its data set)",
                root / "dataset",
            )
        setting_config(config, s, widths[0], args.steps)  # InputError: size not on the stride
    for w in widths:
        setting_config(config, sizes[0], w, args.steps)
    cuda = str(args.device).startswith("cuda")
    if cuda:
        import torch

        if not torch.cuda.is_available():
            raise InputError("--device cuda: no CUDA GPU on this machine")
    out = Path(args.out)
    say = (lambda *a, **k: None) if args.json else (lambda *a, **k: print(*a, **k, flush=True))
    load_before = os.getloadavg()
    say(
        f"project {root} ({full} px, renderer preset {config.renderer_preset}, test motion "
        f"{motion}); device {args.device}, {args.threads} thread(s) per process; load average "
        f"{load_before[0]:.2f} / {load_before[1]:.2f} / {load_before[2]:.2f} on "
        f"{os.cpu_count()} CPUs"
    )
    kw = {"threads": args.threads, "device": args.device}
    rows: list[dict] = []
    table = {
        "bench": "trade",
        "complete": False,
        "project": str(root),
        "image_size": full,
        "renderer_preset": config.renderer_preset,
        "test_motion": motion,
        "device": args.device,
        "device_name": _device_name(args.device),
        "threads": args.threads,
        "steps": args.steps,
        "settings": {"sizes": sizes, "widths": [f"{b}/{m}" for b, m in widths],
                     "proxy_sizes": list(args.proxy_sizes), "sim_frames": args.sim_frames,
                     "sim_lead_in_s": list(args.sim_lead_in), "timed_frames": args.frames},
        "quality_note": "psnr/ssim/mse: render upsampled bilinearly to the project's size vs "
        "full-resolution ground truth; *_native: vs ground truth area-downsampled to the render "
        "size; *_masked: on the garment region; Joint2Coarse proxy; unseen cameras",
        "load_average_before": list(load_before),
        "rows": rows,
        "pareto": [],
        "proxy_rows": [],
        "proxy_peak_rss_mib": None,
        "neural_vs_simulation": None,
    }  # fmt: skip

    def save() -> None:  # after every part, so a long run killed late keeps what it measured
        table["pareto"] = [rows[i]["label"] for i in pareto_front(_points(rows))]
        table["load_average_after"] = list(os.getloadavg())
        write_json(out / "trade.json", table)

    say(f"{len(sizes) * len(widths)} settings x {args.steps} training steps")
    say(HEADER)
    for size in sizes:
        for b, m in widths:
            label = f"{size}px {b}/{m}"
            run_dir = out / "runs" / f"{size}px-{b}x{m}"
            tr = spawned("train_setting", project=str(root), size=size, widths=(b, m),
                         steps=args.steps, out_dir=str(run_dir), **kw)  # fmt: skip
            inf = spawned("infer_setting", project=str(root), model=tr["model"], size=size,
                          frames=args.frames, motion=motion, **kw)  # fmt: skip
            q, qn = inf["quality"], inf["quality_native"]
            row = {
                "label": label, "size": size, "base_width": b, "max_width": m,
                "steps": args.steps, "parameters": tr["parameters"],
                "train_seconds": tr["train_seconds"], "seconds_per_step": tr["seconds_per_step"],
                "skipped_steps": tr["skipped_steps"],
                "train_peak_rss_mib": tr["peak_rss_mib"],
                "train_cuda_peak_mib": tr.get("cuda_peak_mib"),
                "joint2coarse_ms": inf["joint2coarse_ms"],
                "raster_feat_ms": inf["raster_feat_ms"], "network_ms": inf["network_ms"],
                "frame_ms": inf["frame_ms"], "fps": 1e3 / inf["frame_ms"],
                "background_ms": inf["background_ms"], "crop": inf["crop"],
                "timed_frames": inf["timed_frames"],
                "infer_peak_rss_mib": inf["peak_rss_mib"],
                "infer_cuda_peak_mib": inf.get("cuda_peak_mib"),
                "psnr": _metric(q, "psnr"), "ssim": _metric(q, "ssim"), "mse": _metric(q, "mse"),
                "psnr_masked": _metric(q, "psnr_masked"),
                "ssim_masked": _metric(q, "ssim_masked"), "mse_masked": _metric(q, "mse_masked"),
                "psnr_native": _metric(qn, "psnr"), "ssim_native": _metric(qn, "ssim"),
                "quality": q, "quality_native": qn, "test_samples": inf["test_samples"],
                "model": tr["model"], "load_average": os.getloadavg()[0],
            }  # fmt: skip
            rows.append(row)
            save()
            say(format_row(row))
    if args.proxy_sizes:
        proxy = spawned(
            "proxy_axis", project=str(root), sizes=list(args.proxy_sizes), frames=args.frames, **kw
        )
        proxy_rows = table["proxy_rows"] = proxy["rows"]
        table["proxy_peak_rss_mib"] = proxy["peak_rss_mib"]
        save()
        say("\nproxy size (speed only; accuracy = proxy-to-target Hausdorff at rest, not images)")
        say(f"{'target':>6} {'verts':>6} {'faces':>6} {'j2c ms':>7} {'raster+feat':>11} "
            f"{'j2c+raster':>10} {'(+net)':>7} {'Hausdorff':>9}")  # fmt: skip
        for p in proxy_rows:
            say(
                f"{p['target_verts']:>6} {p['vertices']:>6} {p['faces']:>6} "
                f"{p['joint2coarse_ms']:>7.2f} {p['raster_feat_ms']:>11.1f} "
                f"{p['frame_ms']:>10.1f} {p['network_ms']:>7.1f} {100 * p['hausdorff_rel']:>8.2f}%"
            )
    if args.sim_frames:
        # The bench's renderer at the project's size and preset widths (speed does not depend
        # on the weights), else the project's own.
        preset_widths = (preset_cfg.base_width, preset_cfg.max_width)
        same = [r for r in rows if (r["size"], r["base_width"], r["max_width"])
                == (full, *preset_widths)]  # fmt: skip
        at_full = [r for r in rows if r["size"] == full]
        model = Path((same or at_full)[0]["model"]) if same or at_full else None
        if model is None:
            model = root / "renderer" / "renderer.pt"
            if not model.is_file():
                raise InputError(
                    "no renderer to play at the project's size: the project has none and no "
                    "--sizes setting is at its size",
                    model,
                )
        neural = spawned("neural_playback", project=str(root), model=str(model), motion=motion,
                         frames=args.frames, **kw)  # fmt: skip
        sim = spawned("simulate_target", project=str(root), motion=motion,
                      frames=args.sim_frames, lead_in=tuple(args.sim_lead_in), **kw)  # fmt: skip
        ratio = sim["ms_per_frame"] / neural["frame_ms"] if "ms_per_frame" in sim else None
        versus = {"neural": neural, "simulation": sim, "ratio": ratio, "paper_ratio": PAPER_RATIO}
        table["neural_vs_simulation"] = versus
        say("\nneural (Joint2Coarse streaming + raster/features + network) against simulation")
        say(
            f"  neural {neural['frame_ms']:.1f} ms/frame ({1e3 / neural['frame_ms']:.1f} fps) at "
            f"{neural['size']} px on {motion} (+ body background {neural['background_ms']:.1f} "
            f"ms); peak RSS {neural['peak_rss_mib']:.0f} MiB"
        )
        if ratio is None:
            say(f"  simulation failed: {sim['error']}")
        else:
            say(
                f"  simulation {sim['ms_per_frame']:.0f} ms/frame "
                f"({1e3 / sim['ms_per_frame']:.2f} fps), {sim['vertices']} vertices, "
                f"{sim['substeps']} substeps x {sim['iterations']} iterations "
                f"({sim['setting']} setting), {sim['frames']} frames, max edge strain "
                f"{sim['strain_max']:.2f}; peak RSS "
                f"{sim['peak_rss_mib']:.0f} MiB"
            )
            for a in sim["attempts"]:
                if "error" in a:
                    say(f"  ({a['setting']} setting {a['substeps']}x{a['iterations']} failed "
                        f"after {a['wall_s']:.0f} s: {a['error'][:160]})")  # fmt: skip
            say(f"  ratio {ratio:.1f}x (paper: {PAPER_RATIO:g}x, 16 fps against 0.5 fps)")
    table["complete"] = True
    save()
    load_after = table["load_average_after"]
    plot(rows, out / "trade.png", title=f"{root.name}: {motion}, {args.steps} steps")
    if args.json:
        print(json.dumps(table, indent=2, default=str))
    else:
        print(
            f"load average after: {load_after[0]:.2f} / {load_after[1]:.2f} / {load_after[2]:.2f}"
        )
        print(f"wrote {out / 'trade.json'} and {out / 'trade.png'}")
    return 0


def _device_name(device: str) -> str:
    if str(device).startswith("cuda"):
        import torch

        return torch.cuda.get_device_name(0)
    return f"{os.cpu_count()} CPUs"


def _points(rows: list[dict]) -> list[tuple[float, float]]:
    return [(r["frame_ms"], r["psnr"] if r["psnr"] is not None else -np.inf) for r in rows]


def plot(rows: list[dict], path, title: str = "") -> None:
    """ms per frame (log) against PSNR, one labelled point per setting, the Pareto front."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5), dpi=100)
    pts = _points(rows)
    for size in sorted({r["size"] for r in rows}):
        sel = [i for i, r in enumerate(rows) if r["size"] == size]
        ax.plot([pts[i][0] for i in sel], [pts[i][1] for i in sel], "o", label=f"{size} px")
    for (x, y), r in zip(pts, rows):
        ax.annotate(r["label"], (x, y), fontsize=7, xytext=(4, 3), textcoords="offset points")
    front = pareto_front(pts)
    if front:
        ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], "k--o", lw=1, ms=11,
                mfc="none", label="Pareto front", zorder=0)  # fmt: skip
    ax.margins(x=0.2, y=0.15)
    ax.set_xscale("log")
    ax.set_xlabel("ms per frame (Joint2Coarse + raster/features + network)")
    ax.set_ylabel("PSNR (dB, at the project's resolution)")
    ax.set_title(f"speed vs accuracy ({title})", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp)
    plt.close(fig)
