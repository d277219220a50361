"""Stage ``joint2coarse``: train Joint2Coarse on the train split, choose on validation, report
the test split, and predict the proxy of every motion (``joint2coarse/``)."""

from __future__ import annotations

import json
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from core.body.colliders import push_out_of_capsules, simulation_colliders
from core.body.mannequin import make_body
from core.body.skinning import pose_body
from core.camera import make_camera
from core.errors import InputError
from core.fileio import write_json, write_npz
from core.mesh import Mesh, load_mesh
from core.project import Project
from core.shading import contact_sheet, render_views, write_png
from core.sim import load_cache
from core.sim.sanity import hem_indices, hem_radius, waist_indices
from pipeline.config import (
    Log,
    PipelineConfig,
    joint2coarse_config,
    joint2coarse_splits,
    quiet,
    sim_config,
)
from pipeline.stages.motions import load_project_motion


def stage_joint2coarse(
    project: Project, config: PipelineConfig, log: Log = quiet, progress: bool = True
) -> dict:
    """Train Joint2Coarse on its training split's proxy simulations; evaluate on the validation
    and test motions.

    Writes the model and loss log (``training.joint2coarse``), ``pred-MOTION.npz`` for the
    training motion and every validation and test motion, and ``report.json`` with the splits,
    per-vertex errors against simulation (mean and 95th percentile in mm) per validation and
    test motion, body penetration of the predictions and of the simulation, and inference time
    per frame.
    """
    import torch

    from training.joint2coarse import (
        Joint2CoarseClip,
        joint2coarse_inputs,
        predict_proxy,
        prediction_stretch_limit,
        train_joint2coarse,
    )
    from training.joint2coarse.body_model import body_rig
    from training.joint2coarse.config import PREDICTION_STRETCH, PREDICTION_SWEEPS

    torch.set_num_threads(config.torch_threads)
    cfg = joint2coarse_config(config)
    splits = joint2coarse_splits(config)
    train, extra = splits["train"][0], splits["train"][1:]
    vals, tests = splits["validation"], splits["test"]
    names = [train, *extra, *vals, *tests]
    if len(set(names)) != len(names):
        raise InputError(f"Joint2Coarse's train, validation and test motions {names} must differ")
    caches = {n: project.path(f"sim/{n}-proxy", "cache.npz") for n in names}
    motions = [project.path("motions", f"{n}.bvh") for n in names]
    proxy_file = project.path("proxy", "positions.obj")
    params = {"joint2coarse": cfg.to_dict(), "train": train, "tests": tests}
    params["stretch_limit"] = [PREDICTION_STRETCH, PREDICTION_SWEEPS]  # what its predictions keep
    if config.joint2coarse_compare:
        params["compare"] = list(config.joint2coarse_compare)
    if extra:
        params["extra"] = extra
    if vals:
        params["validation"] = vals
    inputs = [*caches.values(), *motions, proxy_file]  # the proxy: its rig, its strain limit

    def work(out: Path) -> list[str]:
        clips = []
        for name in (train, *extra):
            joints, root_rot = joint2coarse_inputs(load_project_motion(project, name))
            positions = load_cache(caches[name]).positions
            clips.append(Joint2CoarseClip(joints, root_rot, positions, name=name))
        joints, root_rot = clips[0].joints, clips[0].root_rotations
        rig = None
        if cfg.model == "ours":
            rig = body_rig(config.body, load_mesh(proxy_file)[0].vertices, cfg.skin_fade)
        run_cfg, mirror, symmetry = mirror_setting(cfg, proxy_file, log)
        result = train_joint2coarse(clips, out, run_cfg, progress=progress, rig=rig, mirror=mirror)
        report = {
            "config": run_cfg.to_dict(),
            "mirror": symmetry,
            "model": cfg.model,
            "stretch_limit": {"limit": PREDICTION_STRETCH, "sweeps": PREDICTION_SWEEPS},
            "splits": splits,
            "train_motion": train,
            "extra_train_motions": extra,
            "validation_error_mm": {k: asdict(v) for k, v in result.stage_errors.items()},
            "validation_mean_shape_baseline_mm": asdict(result.baseline)
            if result.baseline
            else None,
            "validation_motions": {},
            "motions": {},
            "compare": {},
        }
        outputs = [result.model_path.name, result.log_path.name]
        proxy = load_mesh(proxy_file)[0]
        stretch = prediction_stretch_limit(proxy.vertices, proxy.faces)
        # The training motion's prediction: the proxy the renderer sees at test time.
        pred = predict_proxy(result.net, joints, root_rot, stretch=stretch)
        write_npz(out / f"pred-{train}.npz", positions=pred)
        outputs.append(f"pred-{train}.npz")
        for split, key in ((vals, "validation_motions"), (tests, "motions")):
            for name in split:
                report[key][name] = _evaluate_joint2coarse(
                    project, config, result.net, name, load_cache(caches[name]), out,
                    picture=key == "motions", stretch=stretch,
                )  # fmt: skip
                outputs.append(f"pred-{name}.npz")
                if key == "motions":
                    outputs.append(f"compare-{name}.png")
                e = report[key][name]["error_mm"]
                log(
                    f"  {name}: mean {e['mean_mm']:.1f} mm, p95 {e['p95_mm']:.1f} mm "
                    f"({'validation' if key != 'motions' else 'test'} motion)"
                )
        for other in config.joint2coarse_compare:
            if other == cfg.model:
                continue
            log(f"  the {other} model beside it, trained on the same splits")
            other_cfg = replace(run_cfg, model=other)
            other_rig = rig
            if other == "ours" and rig is None:
                rest = load_mesh(proxy_file)[0].vertices
                other_rig = body_rig(config.body, rest, other_cfg.skin_fade)
            folder = out / f"compare-{other}"
            trained = train_joint2coarse(
                clips, folder, other_cfg, progress=progress, rig=other_rig, mirror=mirror
            )
            report["compare"][other] = _compare_errors(project, trained.net, caches, vals, tests)
            outputs.append(f"compare-{other}/{trained.model_path.name}")
        write_json(out / "report.json", report)
        return [*outputs, "report.json"]

    if "ours" in config.joint2coarse_compare and proxy_file not in inputs:
        inputs.append(proxy_file)
    resumable = ["joint2coarse_train.pt"]
    resumable += [f"compare-{m}/joint2coarse_train.pt" for m in config.joint2coarse_compare]
    project.run_stage("joint2coarse", params, inputs, work, resumable=resumable)

    return json.loads(project.path("joint2coarse", "report.json").read_text())


def mirror_setting(cfg, proxy_file: Path, log: Log = quiet) -> tuple:
    """The config Joint2Coarse trains with, the proxy's mirror map and what the report says of
    it. With ``cfg.mirror`` on a garment that is not left-right symmetric (a user's mesh), the
    mirrored clips are left out, said in the log and the report, rather than the run failing at
    its Joint2Coarse stage.

    Returns
    -------
    (Joint2CoarseConfig, MirrorMap or None, dict or None): the dict (None without ``mirror``)
    holds ``used`` and ``asymmetry_mm`` (the largest distance from a rest vertex's mirror image
    to the rest proxy) and ``size_mm`` (its bounding-box diagonal).
    """
    from training.joint2coarse.augment import MAX_ASYMMETRY, mirror_map

    if not cfg.mirror:
        return cfg, None, None
    rest = load_mesh(proxy_file)[0]
    mirror = mirror_map(rest.vertices, rest.faces, str(proxy_file))
    said = {
        "used": mirror.symmetric,
        "asymmetry_mm": 1000 * mirror.asymmetry,
        "size_mm": 1000 * mirror.size,
    }
    if mirror.symmetric:
        return cfg, mirror, said
    log(
        f"  the garment is not left-right symmetric ({said['asymmetry_mm']:.0f} mm off, over "
        f"{100 * MAX_ASYMMETRY:.0f}% of its {said['size_mm']:.0f} mm): Joint2Coarse trains "
        "without mirrored clips"
    )
    return replace(cfg, mirror=False), None, said


def _compare_errors(project: Project, net, caches: dict, vals: list, tests: list) -> dict:
    """A comparison model's vertex errors (mm) on the validation and test motions."""
    from training.joint2coarse import joint2coarse_inputs, predict_proxy, vertex_errors

    out: dict[str, dict] = {"validation_motions": {}, "motions": {}}
    for split, key in ((vals, "validation_motions"), (tests, "motions")):
        for name in split:
            joints, root_rot = joint2coarse_inputs(load_project_motion(project, name))
            pred = predict_proxy(net, joints, root_rot)
            error = vertex_errors(pred, load_cache(caches[name]).positions)
            out[key][name] = {"error_mm": asdict(error)}
    return out


def _evaluate_joint2coarse(
    project, config, net, name, reference, out: Path, picture: bool = True, stretch=None
) -> dict:
    """Predict a test motion; compare with its simulation, with and without the push-out
    against the body (the capsules the simulation collides with); time the inference; write a
    side-by-side picture. Penetration, stretch (edge strain against the proxy's rest shape, p99
    and max over every edge and frame) and the hem's radius per frame (its mean distance from the
    axis through the waist's centroid, mm) are reported for the prediction and the simulation
    alike: a prediction close in millimetres but stretched or inside the body is not close.
    ``stretch``: the strain limit of the project's predictions (:func:`prediction_stretch_limit`)."""
    from training.joint2coarse import (
        Joint2CoarseStream,
        joint2coarse_inputs,
        predict_proxy,
        reconstruct_proxy,
        vertex_errors,
    )

    motion = load_project_motion(project, name)
    joints, root_rot = joint2coarse_inputs(motion)
    start = time.perf_counter()
    pred = predict_proxy(net, joints, root_rot, stretch=stretch)
    ms = 1e3 * (time.perf_counter() - start) / len(pred)
    stream = Joint2CoarseStream(net, stretch=stretch)  # one frame at a time, as the GUI plays
    frame_ms = []
    for t in range(len(joints)):
        start = time.perf_counter()
        stream.push(joints[t], root_rot[t])
        frame_ms.append(1e3 * (time.perf_counter() - start))
    body = make_body(config.body)
    rest = load_mesh(project.path("proxy", "positions.obj"))[0].vertices
    top = float(rest[:, 1].max())
    capsules, radii = simulation_colliders(
        config.body, motion, top, sim_config(config).arm_colliders
    )
    pushed = push_out_of_capsules(pred, capsules, radii)  # predict_proxy's push, done once
    write_npz(out / f"pred-{name}.npz", positions=pred)

    def measured(positions: np.ndarray) -> dict:
        return {
            "error_mm": asdict(vertex_errors(positions, reference.positions)),
            **proxy_physics(positions, rest, reference.faces, capsules, radii),
        }

    if picture:
        _side_by_side(out / f"compare-{name}.png", reference, pred, body, motion)
    extra = {}
    if hasattr(net, "shape_encoder"):  # the paper's model
        # What the decoder reaches from the shapes themselves, encoded (no motion involved).
        rebuilt = reconstruct_proxy(net, reference.positions, joints, root_rot)
        extra["autoencoder_error_mm"] = asdict(vertex_errors(rebuilt, reference.positions))
    return {
        "frames": int(len(pred)),
        **measured(pred),
        "with_push_out": measured(pushed),
        **{
            f"simulation_{k}": v
            for k, v in measured(reference.positions).items()
            if k in ("penetration_mm", "stretch", "hem_radius_mm")
        },
        **extra,
        "batch_ms_per_frame": ms,
        "streaming_ms_per_frame": {
            "median": float(np.median(frame_ms)),
            "p95": float(np.percentile(frame_ms, 95)),
        },
    }


def proxy_physics(
    positions: np.ndarray,
    rest: np.ndarray,
    faces: np.ndarray,
    capsules: np.ndarray,
    radii: np.ndarray,
) -> dict:
    """A proxy's motion judged as cloth, for a prediction and a simulation alike: its
    penetration of the body's capsules, its edges' stretch against the rest shape and its hem's
    radius per frame.

    Parameters
    ----------
    positions : (T, V, 3) metres; rest : (V, 3) the proxy at rest; faces : (F, 3) int
    capsules : (T, K, 2, 3) the body's capsules per frame; radii : (K,)

    Returns
    -------
    dict: ``penetration_mm`` (``mean``, ``max`` mm over every frame and vertex, ``fraction`` of
    them inside), ``stretch`` (``p99``, ``max`` of the edges' strain over every edge and frame),
    ``hem_radius_mm`` (T,) the hem's mean distance from the axis through the waist's centroid
    (:func:`core.sim.sanity.hem_radius`)
    """
    from core.sim.embed import strain_stats  # scipy: not at the CLI's import
    from training.joint2coarse.collision import penetration_summary

    pen = penetration_summary(positions, capsules, radii)
    strain = strain_stats(positions, rest, faces)
    hem, waist = hem_indices(rest, faces), waist_indices(rest, faces)
    radius = 1e3 * hem_radius(positions, hem, waist)
    return {
        "penetration_mm": {
            "mean": pen["mean_mm"],
            "max": pen["max_mm"],
            "fraction": pen["inside_percent"] / 100.0,
        },
        "stretch": {"p99": strain.stretch_p99, "max": strain.stretch_max},
        "hem_radius_mm": [round(float(r), 2) for r in radius],
    }


def _side_by_side(path: Path, reference, predicted: np.ndarray, body, motion) -> None:
    """Simulated proxy above, Joint2Coarse's prediction below, at five frames of the clip."""
    frames = np.linspace(0, len(predicted) - 1, 5).round().astype(int)
    posed = pose_body(body, motion)
    tiles, labels = [], []
    for label, cache in (("simulation", reference.positions), ("Joint2Coarse", predicted)):
        for f in frames:
            centre = motion.root_positions[f].astype(np.float64)
            eye = centre + np.array([0.0, 0.1, 2.6])
            cam = make_camera(eye, centre + np.array([0.0, -0.2, 0.0]), width=192, height=192)
            garment = Mesh(np.asarray(cache[f], np.float32), reference.faces)
            (gt,) = render_views(garment, Mesh(posed[f], body.faces), [cam])
            tiles.append(gt.image)
            labels.append(f"{label} f{f}")
    write_png(path, contact_sheet(tiles, labels, columns=len(frames)))


def joint2coarse_prediction(project: Project, motion_name: str) -> np.ndarray:
    """The project's Joint2Coarse prediction of one of its motions, made as the stage makes the
    training motion's (strain-limited, not pushed out of the body): (T, Vs, 3) float32 seam-free
    proxy vertices. Needs the ``joint2coarse`` stage's model."""
    from training.joint2coarse import (
        joint2coarse_inputs,
        load_model,
        predict_proxy,
        prediction_stretch_limit,
    )

    model = project.path("joint2coarse", "joint2coarse.pt")
    if not model.is_file():
        raise InputError("no Joint2Coarse model: run the joint2coarse stage first", model)
    proxy = load_mesh(project.path("proxy", "positions.obj"))[0]
    joints, root_rot = joint2coarse_inputs(load_project_motion(project, motion_name))
    stretch = prediction_stretch_limit(proxy.vertices, proxy.faces)
    return predict_proxy(load_model(model), joints, root_rot, source=motion_name, stretch=stretch)
