"""Stage ``eval``: every method scored from unseen cameras (``eval/report.json``): **V**, the
renderers' validation motion from cameras of its own, where every renderer and baseline setting
is chosen; then, only reported, **U**, the unseen test motions (beyond the paper), and **P**, the
paper's: the training motion itself, from cameras the training never saw. Every method renders
Joint2Coarse's proxy in each, and the simulated proxy beside it (the renderers alone)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from core.errors import InputError
from core.fileio import write_json
from core.project import Project
from core.shading import contact_sheet, write_png
from pipeline.config import (
    Log,
    PipelineConfig,
    available_test_motions,
    quiet,
    renderer_validation_motion,
)
from pipeline.stages.ablations import (
    RENDERER_ABLATIONS,
    ablation_label,
    ablation_project,
    check_ablation,
)
from training.dataset import GarmentDataset


def eval_methods(project: Project, config: PipelineConfig) -> dict[str, tuple[Path, str, Path]]:
    """The methods ``stage_eval`` scores: name -> (model file, proxy source at test time,
    project folder whose proxy and test sets it renders).

    ``ours`` renders Joint2Coarse's proxy (no simulation at test time, the method's claim);
    ``ours (simulated proxy)`` renders the simulated proxy of the same motion, which separates
    the renderer's error from Joint2Coarse's. Baselines render both proxies too; ablations
    render Joint2Coarse's.
    """
    root = project.root
    methods = {
        "ours": (project.path("renderer", "renderer.pt"), "joint2coarse", root),
        "ours (simulated proxy)": (project.path("renderer", "renderer.pt"), "sim", root),
    }
    for kind in config.baselines:
        methods[kind] = (project.path(f"baselines/{kind}", f"{kind}.pt"), "joint2coarse", root)
    for kind in config.baselines:  # the renderers alone, on the right geometry
        model = project.path(f"baselines/{kind}", f"{kind}.pt")
        methods[f"{kind} (simulated proxy)"] = (model, "sim", root)
    for name in config.ablations:
        check_ablation(name)
        if name in RENDERER_ABLATIONS:
            model, data = project.path(f"ablations/{name}", "renderer.pt"), root
        elif name.startswith("views-"):
            model, data = ablation_project(project, name).path("renderer", "renderer.pt"), root
        else:
            sub = ablation_project(project, name)
            model, data = sub.path("renderer", "renderer.pt"), sub.root
        methods[ablation_label(name, config)] = (model, "joint2coarse", data)
    return methods


def ours_to_dnr(methods: dict) -> dict:
    """Our MSE over DNR's, full frame (``mse_ratio_ours_to_dnr``) and on the garment region
    (``mse_masked_ratio_ours_to_dnr``), on Joint2Coarse's proxy and, with the suffix
    ``_simulated_proxy``, on the simulated one: those of the pairs that both ran and have a mean."""
    out = {}
    for suffix in ("", " (simulated proxy)"):
        ours, dnr = methods.get(f"ours{suffix}"), methods.get(f"dnr{suffix}")
        if not (ours and dnr):
            continue
        for metric in ("mse", "mse_masked"):
            mine, theirs = ours[metric]["mean"], dnr[metric]["mean"]
            if mine is not None and theirs:
                key = f"{metric}_ratio_ours_to_dnr" + ("_simulated_proxy" if suffix else "")
                out[key] = mine / theirs
    return out


def eval_motions(config: PipelineConfig) -> dict[str, str]:
    """The motions ``stage_eval`` scores, in its order, with their protocols: the renderers'
    validation motion (``"V, validation"``), the test motions (``"U"``), then the training
    motion (``"P, the training motion"``)."""
    validation = renderer_validation_motion(config)
    motions = {validation.name: "V, validation"} if validation else {}
    motions.update({m.name: "U" for m in available_test_motions(config)})
    motions[config.train_motion.name] = "P, the training motion"
    return motions


def stage_eval_motion(
    project: Project, config: PipelineConfig, motion: str, log: Log = quiet
) -> dict:
    """One motion of :func:`stage_eval`, scored from its unseen cameras (``testset/MOTION``):
    ``eval/MOTION/scores.json`` (per method: the summary of each metric, FID and video FID,
    and every frame's finite metric values, which the report pools over the test motions) and
    ``eval/MOTION/compare.png`` (ground truth and each method on the same frames).

    The training motion (protocol P) scores the methods of this project's own proxy (an
    ablation's sub-project with another proxy has no test set of it); every other motion,
    every method. The motions are apart so that two processes can share them (``dng demo``).
    """
    import torch

    from training.baselines import load_for_evaluation
    from training.evaluate import EvalConfig, evaluate_motion, weights_scores
    from training.metrics import METRICS as metric_names

    protocols = eval_motions(config)
    if motion not in protocols:
        raise InputError(f"{motion!r} is not a motion the evaluation scores: {list(protocols)}")
    methods = eval_methods(project, config)
    if motion == config.train_motion.name:
        methods = {n: m for n, m in methods.items() if m[2] == project.root}
    eval_cfg = EvalConfig(inception_path=config.inception_path, lpips_path=config.lpips_path)
    inputs = [path for path, _, _ in methods.values()]
    for root in sorted({r for _, _, r in methods.values()}):
        data = Project(root)
        inputs += [
            data.path(f"testset/{motion}", "samples.json"),
            data.path("joint2coarse", f"pred-{motion}.npz"),
            data.path(f"sim/{motion}-proxy", "cache.npz"),
        ]
    params = {
        "eval": eval_cfg.to_dict(),
        "methods": {k: [v[1], str(v[2])] for k, v in methods.items()},
        "metrics": list(metric_names),
    }

    def work(out: Path) -> list[str]:
        torch.set_num_threads(config.torch_threads)
        models = {name: load_for_evaluation(path) for name, (path, _, _) in methods.items()}
        data = {
            (root, src): GarmentDataset(
                root, source=src, split=motion, threads=config.raster_threads
            )
            for _, src, root in methods.values()
        }
        log(
            f"  evaluating {motion} ({protocols[motion]}): "
            f"{len(data[(project.root, 'joint2coarse')])} samples x {len(methods)} methods"
        )
        results, gt_tiles = evaluate_motion(
            {name: (models[name], data[(root, src)]) for name, (_, src, root) in methods.items()},
            eval_cfg,
        )
        scores, values = {}, {}
        for name, r in results.items():
            scores[name] = {
                "samples": len(data[(methods[name][2], methods[name][1])]),
                **r.metrics.summary(),
                **weights_scores(r, eval_cfg),
            }
            values[name] = {
                metric: [v for v in vs if math.isfinite(v)]
                for metric, vs in r.metrics.values.items()
            }
        tiles, labels = [], []
        for row_name, row in (
            ("ground truth", gt_tiles),
            *((n, r.tiles) for n, r in results.items()),
        ):
            tiles += row
            labels += [row_name] * len(row)
        write_png(out / "compare.png", contact_sheet(tiles, labels, columns=len(gt_tiles)))
        report = {"motion": motion, "protocol": protocols[motion], "methods": scores}
        write_json(out / "scores.json", {**report, "values": values})
        return ["compare.png", "scores.json"]

    project.run_stage(f"eval/{motion}", params, inputs, work)
    return json.loads(project.path(f"eval/{motion}", "scores.json").read_text())


def stage_eval(project: Project, config: PipelineConfig, log: Log = quiet) -> dict:
    """Score every method on the renderers' validation motion (protocol V: ``validation``), on
    every test motion (protocol U: ``methods``, pooled over the test motions, and ``motions``)
    and on the training motion (protocol P: ``protocol_p``), each from unseen cameras
    (``testset/``): ``eval/report.json``, from each motion's :func:`stage_eval_motion` (run
    here where it has not run yet)."""
    from training.metrics import FrameMetrics

    protocols = eval_motions(config)
    for motion in protocols:
        stage_eval_motion(project, config, motion, log)
    scores_files = [project.path(f"eval/{m}", "scores.json") for m in protocols]
    tests = [m for m, p in protocols.items() if p == "U"]
    train = config.train_motion.name

    def work(out: Path) -> list[str]:
        report: dict = {"methods": {}, "motions": {}, "test_motions": tests}
        totals: dict[str, FrameMetrics] = {}
        p: dict = {}
        for motion, path in zip(protocols, scores_files):
            scored = json.loads(path.read_text())
            if motion in tests:
                report["motions"][motion] = scored["methods"]
                for name, values in scored["values"].items():
                    pooled = totals.setdefault(name, FrameMetrics())
                    for metric, vs in values.items():
                        pooled.add(metric, vs)
            elif motion == train:
                p = {"motion": motion, "methods": _pooled(scored["values"])}
            else:
                v = {"motion": motion, "methods": scored["methods"]}
                report["validation"] = {**v, **ours_to_dnr(v["methods"])}
        report["methods"] = {name: pooled.summary() for name, pooled in totals.items()}
        report.update(ours_to_dnr(report["methods"]))
        report["protocol_p"] = {**p, **ours_to_dnr(p["methods"])}
        write_json(out / "report.json", report)
        return ["report.json"]

    project.run_stage("eval", {"motions": protocols}, scores_files, work)
    return json.loads(project.path("eval", "report.json").read_text())


def _pooled(values: dict[str, dict[str, list[float]]]) -> dict:
    """Each method's summary of its frames' metric values (:meth:`FrameMetrics.summary`)."""
    from training.metrics import FrameMetrics

    out = {}
    for name, metrics in values.items():
        frames = FrameMetrics()
        for metric, vs in metrics.items():
            frames.add(metric, vs)
        out[name] = frames.summary()
    return out
