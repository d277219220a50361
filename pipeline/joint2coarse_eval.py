"""``dng eval joint2coarse``: how close a project's Joint2Coarse comes to the simulation on any
motion, the question every user has before trusting the preview.

The motion (a BVH file on any rig, or a procedural kind) is retargeted onto the project's
mannequin, the proxy is simulated under it with the project's fabric, substeps and fps (the
simulation is cached in a scratch folder outside the project, keyed by a hash of everything
that decides it), Joint2Coarse predicts the same frames, and the two are compared: vertex error
(mean, 95th percentile, max, mm), and the physics of both alike: body penetration against the
capsules the simulation collides with, stretch (edge strain, p99 and max) and the hem's radius
(:func:`pipeline.stages.joint2coarse.proxy_physics`); and milliseconds per frame of both. With
``floor``, the proxy is simulated again moved 10 um at random (:data:`core.sim.sanity.FLOOR_PERTURBATION_M`): where the cloth buckles
its folds go one way or the other, so the simulation is only this close to itself, and no
prediction can be expected to come much closer (docs/decisions.md, "What counts as converged"). With
``realisations`` N, the proxy is simulated N more times, each moved 10 um by offsets of its own
(the first is the floor's), and every model is scored against each of the N + 1 simulations:
a figure measured against one simulation is one draw of where the folds went, and on a motion
where they can go more than one way it moves by millimetres from one draw to the next. From
N = 2 on, the mean of the other simulations is scored against each too: the motion's likely
outcome, about the best any prediction can do, and each model's **ensemble ratio**, its mean
error over that one's (:func:`realisation_errors`).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import asdict
from itertools import combinations
from pathlib import Path

import numpy as np

from core.body.colliders import push_out_of_capsules, simulation_colliders
from core.errors import InputError
from core.fileio import write_json
from core.mesh import load_mesh
from core.motion.motion import Motion
from core.motion.procedural import PROCEDURAL_KINDS
from core.project import Project
from core.sim import load_cache, save_cache
from core.sim.sanity import FLOOR_PERTURBATION_M, perturbed
from pipeline.config import Log, MotionSpec, PipelineConfig, quiet, sim_config
from pipeline.stages.joint2coarse import proxy_physics
from pipeline.stages.motions import motion_from_spec
from pipeline.stages.simulate import proxy_thickness

#: Frames of a procedural kind when ``--frames`` is not given (5 s at 30 fps).
DEFAULT_KIND_FRAMES = 150
#: Bumped when the cached simulation's layout or meaning changes.
CACHE_VERSION = 1


def scratch_dir() -> Path:
    """Where evaluation simulations are cached: ``$XDG_CACHE_HOME/garment-studio/
    joint2coarse-eval`` (``~/.cache`` when unset), never inside a project."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "garment-studio" / "joint2coarse-eval"


def eval_motion(
    config: PipelineConfig,
    motion: str,
    frames: int | None = None,
    start_s: float = 0.0,
    seed: int = 0,
) -> Motion:
    """The motion to evaluate on, on the project's mannequin at the project's fps.

    Parameters
    ----------
    config : the project's settings (body, fps)
    motion : a BVH file (any rig: retargeted), or a procedural kind (``PROCEDURAL_KINDS``)
    frames : frames to keep; default: the rest of the file after ``start_s``, or
        :data:`DEFAULT_KIND_FRAMES` of a kind
    start_s : seconds of the file to skip (motion capture often starts in a T-pose)
    seed : seed of a procedural kind

    Raises
    ------
    InputError
        Unknown kind, bad or unreadable BVH, a start past the clip's end, ``frames`` < 1.
    """
    from core.motion.load import load_motion, resample

    if frames is not None and frames < 1:
        raise InputError(f"--frames must be at least 1, got {frames}", motion)
    if not (np.isfinite(start_s) and start_s >= 0):
        raise InputError(f"--start-s must be >= 0 seconds, got {start_s}", motion)
    if motion in PROCEDURAL_KINDS:
        spec = MotionSpec(motion, motion, frames or DEFAULT_KIND_FRAMES, seed=seed)
        return motion_from_spec(spec, config)
    path = Path(motion)
    if not path.is_file():
        raise InputError(
            f"no such BVH file, and not a procedural kind ({', '.join(PROCEDURAL_KINDS)})", path
        )
    if frames is None:
        total = resample(load_motion(path), config.fps).num_frames
        frames = total - int(round(start_s * config.fps))
        if frames < 1:
            raise InputError(f"the clip is shorter than --start-s {start_s:g} s", path)
    spec = MotionSpec(path.stem, "file", frames, path=str(path), start_s=start_s)
    return motion_from_spec(spec, config)


def simulation_key(positions: np.ndarray, faces: np.ndarray, motion: Motion, params: dict) -> str:
    """SHA-256 of everything that decides a simulation: the rest garment (V, 3) and its faces
    (F, 3), the motion's rotations, root positions and fps, and ``params`` (body, sim config)."""
    h = hashlib.sha256(f"v{CACHE_VERSION}".encode())
    h.update(json.dumps(params, sort_keys=True, default=str).encode())
    for a in (positions, faces, motion.rotations, motion.root_positions):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(a.tobytes())
    h.update(repr(float(motion.fps)).encode())
    return h.hexdigest()


def simulate_cached(
    project: Project,
    config: PipelineConfig,
    motion: Motion,
    log: Log = quiet,
    cache_root: Path | None = None,
    moved_m: float = 0.0,
    moved_seed: int = 0,
):
    """The proxy simulated under ``motion`` with the project's settings, from the scratch cache
    (``cache_root``, default :func:`scratch_dir`) when it holds this exact simulation;
    ``moved_m`` > 0: the proxy's rest vertices moved first by a normal offset of that standard
    deviation (metres; :func:`core.sim.sanity.perturbed`), drawn from ``moved_seed``.

    Returns
    -------
    cache : core.sim.SimCache, positions (T, V, 3)
    report : dict, the simulation's report (``ms_per_frame``...)
    folder : Path of the cache entry
    cached : bool, whether it came from the cache
    """
    from core.sim.simulate import simulate

    mesh, proxy_file = project_proxy(project)
    sim_cfg = sim_config(config)
    thickness = proxy_thickness(project, mesh) if config.layer_thickness else None
    if moved_m > 0:
        mesh = perturbed(mesh, moved_m, moved_seed)
    params = {
        "sim": sim_cfg.as_dict(),
        "body": asdict(config.body),
        "layer_thickness_mm": None if thickness is None else np.round(1e3 * thickness, 3).tolist(),
    }
    key = simulation_key(mesh.vertices, mesh.faces, motion, params)
    folder = (cache_root or scratch_dir()) / key[:32]
    cache_file, report_file = folder / "cache.npz", folder / "report.json"
    if cache_file.is_file() and report_file.is_file():
        try:
            report = json.loads(report_file.read_text(encoding="utf-8"))
            return load_cache(cache_file), report, folder, True
        except (InputError, ValueError, OSError):
            log(f"  cached simulation in {folder} is unreadable: simulating again")
    moved = f", moved {moved_m * 1e6:g} um" if moved_m > 0 else ""
    log(f"  simulating the proxy{moved} ({motion.num_frames} frames; cached in {folder})")
    cache, report = simulate(
        mesh, motion, config.body, sim_cfg, path=proxy_file, thickness=thickness
    )
    folder.mkdir(parents=True, exist_ok=True)
    save_cache(cache_file, cache)
    write_json(report_file, report.as_dict())
    return cache, report.as_dict(), folder, False


def evaluate_on_motion(
    project: Project,
    config: PipelineConfig,
    motion: Motion,
    source: str,
    log: Log = quiet,
    cache_root: Path | None = None,
    floor: bool = False,
    realisations: int = 0,
) -> dict:
    """Joint2Coarse against the simulation on one motion (already on the mannequin); with
    ``floor``, the simulation against itself on the proxy moved 10 um too (``simulation_floor_mm``);
    with ``realisations`` N > 0, against N more simulations too, each of the proxy moved 10 um
    by offsets of its own (``realisations``: :func:`realisation_errors`).

    Raises
    ------
    InputError
        No trained Joint2Coarse in the project; a motion shorter than its descriptor window;
        ``realisations`` below 0.
    """
    import torch

    from training.joint2coarse import (
        Joint2CoarseStream,
        joint2coarse_inputs,
        load_model,
        predict_proxy,
        prediction_stretch_limit,
        vertex_errors,
    )

    torch.set_num_threads(config.torch_threads)
    model_file = project.path("joint2coarse", "joint2coarse.pt")
    if not model_file.is_file():
        raise InputError(
            "the project has no trained Joint2Coarse: run dng train joint2coarse first", model_file
        )
    if not (isinstance(realisations, int) and realisations >= 0):
        raise InputError(f"realisations must be an integer >= 0, got {realisations!r}", source)
    net = load_model(model_file)
    window = net.config.window
    if motion.num_frames < window:
        raise InputError(
            f"the motion has {motion.num_frames} frames, fewer than Joint2Coarse's descriptor "
            f"window of {window} frames",
            source,
        )
    reference, sim_report, folder, cached = simulate_cached(
        project, config, motion, log, cache_root
    )
    joints, root_rot = joint2coarse_inputs(motion)
    proxy = project_proxy(project)[0]
    stretch = prediction_stretch_limit(proxy.vertices, proxy.faces)
    start = time.perf_counter()
    pred = predict_proxy(net, joints, root_rot, source=source, stretch=stretch)
    batch_ms = 1e3 * (time.perf_counter() - start) / len(pred)
    stream = Joint2CoarseStream(net, stretch=stretch)
    frame_ms = []
    for t in range(len(joints)):
        start = time.perf_counter()
        stream.push(joints[t], root_rot[t])
        frame_ms.append(1e3 * (time.perf_counter() - start))
    rest = proxy.vertices
    top = float(rest[:, 1].max())
    ends, radii = simulation_colliders(config.body, motion, top, sim_config(config).arm_colliders)
    start = time.perf_counter()  # the push-out alone, on the prediction (as predict_proxy's)
    pushed = push_out_of_capsules(pred, ends, radii)
    push_ms = 1e3 * (time.perf_counter() - start) / len(pred)
    compare = {}  # the models trained beside the project's (joint2coarse_compare)
    predictions = {net.config.model: pred}
    for path in sorted(project.stage_dir("joint2coarse").glob("compare-*/joint2coarse.pt")):
        other = load_model(path)
        if motion.num_frames >= other.config.window:
            pred_other = predict_proxy(other, joints, root_rot, source=source)
            compare[other.config.model] = asdict(vertex_errors(pred_other, reference.positions))
            predictions.setdefault(other.config.model, pred_other)
    # the proxy moved 10 um, offsets of seeds 0, 1, ...: the floor is the first of them
    moved = [
        simulate_cached(
            project, config, motion, log, cache_root, FLOOR_PERTURBATION_M, moved_seed=i
        )[0].positions
        for i in range(max(realisations, int(floor)))
    ]
    floor_mm = floor_seconds = None
    if floor:
        floor_mm = asdict(vertex_errors(moved[0], reference.positions))
        floor_seconds = errors_per_second(moved[0], reference.positions, motion.fps)
    realised = None
    if realisations:
        realised = realisation_errors(predictions, [reference.positions, *moved])
    physics = {
        name: proxy_physics(positions, rest, reference.faces, ends, radii)
        for name, positions in (
            ("prediction", pred), ("prediction_pushed_out", pushed),
            ("simulation", reference.positions),
        )
    }  # fmt: skip
    sim_hem = np.asarray(physics["simulation"]["hem_radius_mm"])
    return {
        "project": str(project.root),
        "model": net.config.model,
        "motion": source,
        "frames": int(len(pred)),
        "fps": float(motion.fps),
        "vertices": int(pred.shape[1]),
        "error_mm": asdict(vertex_errors(pred, reference.positions)),
        "error_mm_per_second": errors_per_second(pred, reference.positions, motion.fps),
        "error_mm_pushed_out": asdict(vertex_errors(pushed, reference.positions)),
        "penetration": {  # penetration_summary's keys, from the physics measured once
            name: {
                "inside_percent": 100.0 * p["penetration_mm"]["fraction"],
                "mean_mm": p["penetration_mm"]["mean"],
                "max_mm": p["penetration_mm"]["max"],
            }
            for name, p in physics.items()
        },
        "stretch": {name: p["stretch"] for name, p in physics.items()},
        "hem_radius_mm": {
            name: {
                "mean": float(np.mean(p["hem_radius_mm"])),
                "mean_difference": float(np.mean(np.abs(np.asarray(p["hem_radius_mm"]) - sim_hem))),
            }
            for name, p in physics.items()
        },
        "ms_per_frame": {
            "simulation": float(sim_report["ms_per_frame"]),
            "prediction": batch_ms,
            "prediction_streaming": float(np.median(frame_ms)),
            "push_out": push_ms,
        },
        "compare_error_mm": compare,
        "simulation_floor_mm": floor_mm,
        "simulation_floor_mm_per_second": floor_seconds,
        "realisations": realised,
        "simulation_cache": str(folder),
        "simulation_from_cache": cached,
    }


def realisation_errors(predictions: dict, simulations: list) -> dict:
    """Every model against every simulation of the same motion, and the simulations against
    each other: how much a figure measured against one of them is a draw.

    Parameters
    ----------
    predictions : {model name: (T, V, 3) prediction}, metres
    simulations : list of S (T, V, 3) simulations of the motion, metres (the first the
        reference, the rest of the proxy moved 10 um)

    Returns
    -------
    dict: ``simulations`` S; ``error_mm`` {model: ``mean_mm``, ``p95_mm`` (means over the S),
    ``mean_mm_each`` (S,)}; ``between_simulations_mm``: ``mean_mm``, ``p95_mm`` (means over the
    S (S - 1) / 2 pairs), ``mean_mm_each``; ``mean_of_others_mm`` (S >= 3, else None): the mean
    of the other S - 1 simulations, vertex by vertex, against each one, the same three keys;
    ``ensemble_ratio`` (S >= 3, else None): {model: its ``mean_mm`` over the mean of the
    others' ``mean_mm``}, Joint2Coarse's headline (1: as close as the likely outcome comes).

    The mean of the others is a prediction no model can beat by much: the likely outcome of the
    motion, estimated from S - 1 draws, scored against a draw it has not seen. A model at that
    figure has learned all of the motion that the cloth repeats; what is left is where the
    folds went this time. (From S - 1 draws the estimate carries a little of their own scatter:
    with errors independent from vertex to vertex, its mean squared error is ``1 + 1 / (S - 1)``
    times the true likely outcome's.)
    """
    from training.joint2coarse import vertex_errors

    def summary(errors: list) -> dict:
        return {
            "mean_mm": float(np.mean([e.mean_mm for e in errors])),
            "p95_mm": float(np.mean([e.p95_mm for e in errors])),
            "mean_mm_each": [float(e.mean_mm) for e in errors],
        }

    count = len(simulations)
    # the mean of the others of each: (their sum - it) / (S - 1)
    total = np.sum(simulations, axis=0, dtype=np.float64)
    errors = {
        model: summary([vertex_errors(pred, sim) for sim in simulations])
        for model, pred in predictions.items()
    }
    others = (
        summary([vertex_errors((total - sim) / (count - 1), sim) for sim in simulations])
        if count >= 3
        else None
    )
    return {
        "simulations": count,
        "error_mm": errors,
        "between_simulations_mm": summary(
            [vertex_errors(a, b) for a, b in combinations(simulations, 2)]
        ),
        "mean_of_others_mm": others,
        "ensemble_ratio": {m: e["mean_mm"] / others["mean_mm"] for m, e in errors.items()}
        if others and others["mean_mm"] > 0
        else None,
    }


def errors_per_second(predicted: np.ndarray, reference: np.ndarray, fps: float) -> list[dict]:
    """Where along the motion the prediction goes wrong: the vertex error of each second.

    predicted, reference : (T, V, 3) metres. Returns one dict per window of ``round(fps)``
    frames (the last may be shorter): ``start_s`` and the window's ``mean_mm``, ``p95_mm``,
    ``max_mm``."""
    from training.joint2coarse import vertex_errors

    step = max(1, round(fps))
    return [
        {
            "start_s": i / fps,
            **asdict(vertex_errors(predicted[i : i + step], reference[i : i + step])),
        }
        for i in range(0, len(predicted), step)
    ]


def project_proxy(project: Project):
    """The project's proxy in its rest pose (``proxy/positions.obj``) and that file's path."""
    path = project.path("proxy", "positions.obj")
    if not path.is_file():
        raise InputError("the project has no proxy: run dng demo or dng proxy first", path)
    return load_mesh(path)[0], path


def format_report(report: dict) -> str:
    """The report as a few lines of text."""
    e, q = report["error_mm"], report["error_mm_pushed_out"]
    p, ms = report["penetration"], report["ms_per_frame"]
    st, hem = report["stretch"], report["hem_radius_mm"]
    lines = [
        f"{report['motion']}: {report['frames']} frames at {report['fps']:g} fps, "
        f"{report['vertices']} proxy vertices",
        f"{'':28s} {'mean mm':>8s} {'p95 mm':>8s} {'max mm':>8s} {'inside %':>9s} "
        f"{'depth max mm':>13s} {'stretch p99':>12s} {'max':>6s} {'hem radius mm':>14s} "
        f"{'ms/frame':>9s}",
    ]
    rows = (
        (f"Joint2Coarse ({report['model']})", e, "prediction", ms["prediction"]),
        ("Joint2Coarse, pushed out", q, "prediction_pushed_out",
         ms["prediction"] + ms["push_out"]),
        ("simulation", None, "simulation", ms["simulation"]),
    )  # fmt: skip
    for name, err, key, t in rows:
        errs = (
            f"{err['mean_mm']:8.1f} {err['p95_mm']:8.1f} {err['max_mm']:8.1f}"
            if err
            else f"{'-':>8s} {'-':>8s} {'-':>8s}"
        )
        pen, s = p[key], st[key]
        lines.append(
            f"{name:28s} {errs} {pen['inside_percent']:9.2f} {pen['max_mm']:13.1f} "
            f"{s['p99']:12.3f} {s['max']:6.3f} {hem[key]['mean']:14.1f} {t:9.2f}"
        )
    lines.append(
        "the hem's radius (its mean distance from the waist's axis) differs from the "
        f"simulation's by {hem['prediction']['mean_difference']:.1f} mm a frame on average "
        f"({hem['prediction_pushed_out']['mean_difference']:.1f} pushed out)"
    )
    for model, err in report["compare_error_mm"].items():
        lines.append(
            f"{'(' + model + ' model, beside it)':28s} {err['mean_mm']:8.1f} {err['p95_mm']:8.1f} "
            f"{err['max_mm']:8.1f}"
        )
    if report.get("simulation_floor_mm"):
        f = report["simulation_floor_mm"]
        lines.append(
            f"{'simulation, proxy moved 10 um':28s} {f['mean_mm']:8.1f} {f['p95_mm']:8.1f} "
            f"{f['max_mm']:8.1f}   (the floor: how far the simulation is from itself)"
        )
    realised = report.get("realisations")
    if realised:
        lines.append(
            f"against {realised['simulations']} simulations (the proxy moved 10 um in all but "
            "the first), mean / p95 mm over them, the range of the means:"
        )
        rows = [(f"Joint2Coarse ({m})", e) for m, e in realised["error_mm"].items()]
        rows.append(("the simulations, each pair", realised["between_simulations_mm"]))
        if realised.get("mean_of_others_mm"):
            rows.append(("the mean of the others", realised["mean_of_others_mm"]))
        for name, e in rows:
            lines.append(
                f"  {name:26s} {e['mean_mm']:8.1f} {e['p95_mm']:8.1f}   "
                f"({min(e['mean_mm_each']):.1f} to {max(e['mean_mm_each']):.1f})"
            )
        if realised.get("ensemble_ratio"):
            lines.append(
                "ensemble ratio (mean error over the mean of the others', 1 = the likely "
                "outcome's): "
                + ", ".join(f"{m} {r:.2f}x" for m, r in realised["ensemble_ratio"].items())
            )
    seconds = report["error_mm_per_second"]
    if len(seconds) > 1:
        worst = max(seconds, key=lambda w: w["mean_mm"])
        lines.append(
            "mean error each second (mm): "
            + " ".join(f"{w['mean_mm']:.0f}" for w in seconds)
            + f"; the worst from {worst['start_s']:.1f} s (p95 {worst['p95_mm']:.0f} mm)"
        )
        if report.get("simulation_floor_mm_per_second"):
            lines.append(
                "the floor each second (mm):  "
                + " ".join(f"{w['mean_mm']:.0f}" for w in report["simulation_floor_mm_per_second"])
            )
    lines.append(
        f"streaming (one frame at a time): {ms['prediction_streaming']:.2f} ms/frame; simulation "
        f"{'from the cache' if report['simulation_from_cache'] else 'cached'} in "
        f"{report['simulation_cache']}"
    )
    return "\n".join(lines)
