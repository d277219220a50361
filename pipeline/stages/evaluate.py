"""Stage ``eval``: every method scored from unseen cameras (``eval/report.json``): **V**, the
renderers' validation motion from cameras of its own, where every renderer and baseline setting
is chosen; then, only reported, **U**, the unseen test motions (beyond the paper), and **P**, the
paper's: the training motion itself, from cameras the training never saw. Every method renders
Joint2Coarse's proxy in each, and the simulated proxy beside it (the renderers alone)."""

from __future__ import annotations

import json
from pathlib import Path

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


def stage_eval(project: Project, config: PipelineConfig, log: Log = quiet) -> dict:
    """Score every method on the renderers' validation motion (protocol V: ``validation``), on
    every test motion (protocol U: ``methods``, ``motions``) and on the training motion
    (protocol P: ``protocol_p``), each from unseen cameras (``testset/``): ``eval/report.json``
    and ``eval/compare-MOTION.png`` (ground truth and each method on the same frames)."""
    import torch

    from training.baselines import load_for_evaluation
    from training.evaluate import EvalConfig, evaluate_motion, fid_scores
    from training.metrics import FrameMetrics

    tests = [m.name for m in available_test_motions(config)]
    train = config.train_motion.name
    validation = renderer_validation_motion(config)
    checked = [validation.name] if validation else []
    methods = eval_methods(project, config)
    eval_cfg = EvalConfig(inception_path=config.inception_path)
    inputs = [path for path, _, _ in methods.values()]
    for name in [*checked, *tests, train]:
        # protocol P scores the methods of this project's own proxy (an ablation's
        # sub-project with another proxy has no test set of the training motion)
        for root in {r for _, _, r in methods.values()} if name != train else {project.root}:
            data = Project(root)
            inputs += [
                data.path(f"testset/{name}", "samples.json"),
                data.path("joint2coarse", f"pred-{name}.npz"),
                data.path(f"sim/{name}-proxy", "cache.npz"),
            ]
    params = {
        "eval": eval_cfg.to_dict(),
        "methods": {k: [v[1], str(v[2])] for k, v in methods.items()},
    }

    def work(out: Path) -> list[str]:
        torch.set_num_threads(config.torch_threads)
        models = {name: load_for_evaluation(path) for name, (path, _, _) in methods.items()}
        totals = {name: FrameMetrics() for name in methods}
        seen = {name: FrameMetrics() for name in methods}
        report: dict = {"methods": {}, "motions": {}, "test_motions": tests}
        outputs = []
        own = {n: m for n, m in methods.items() if m[2] == project.root}
        for motion in [*checked, *tests, train]:
            scored = methods if motion != train else own
            data = {
                (root, src): GarmentDataset(root, source=src, split=motion)
                for _, src, root in scored.values()
            }
            protocol = {train: "P, the training motion"}.get(
                motion, "V, validation" if motion in checked else "U"
            )
            log(
                f"  evaluating {motion} ({protocol}): {len(data[(project.root, 'joint2coarse')])}"
                f" samples x {len(scored)} methods"
            )
            results, gt_tiles = evaluate_motion(
                {
                    name: (models[name], data[(root, src)])
                    for name, (_, src, root) in scored.items()
                },
                eval_cfg,
            )
            scores = {
                name: {
                    "samples": len(data[(methods[name][2], methods[name][1])]),
                    **r.metrics.summary(),
                }
                for name, r in results.items()
            }
            for name, r in results.items():
                if motion in tests or motion == train:
                    for metric, values in r.metrics.values.items():
                        (seen if motion == train else totals)[name].add(metric, values)
                scores[name].update(fid_scores(r, eval_cfg))
            if motion in tests:
                report["motions"][motion] = scores
            elif motion in checked:
                report["validation"] = {"motion": motion, "methods": scores, **ours_to_dnr(scores)}
            tiles, labels = [], []
            for row_name, row in (
                ("ground truth", gt_tiles),
                *((n, r.tiles) for n, r in results.items()),
            ):
                tiles += row
                labels += [row_name] * len(row)
            write_png(
                out / f"compare-{motion}.png", contact_sheet(tiles, labels, columns=len(gt_tiles))
            )
            outputs.append(f"compare-{motion}.png")
        report["methods"] = {name: totals[name].summary() for name in methods}
        report.update(ours_to_dnr(report["methods"]))
        p = {"motion": train, "methods": {name: seen[name].summary() for name in own}}
        p.update(ours_to_dnr(p["methods"]))
        report["protocol_p"] = p
        write_json(out / "report.json", report)
        return [*outputs, "report.json"]

    project.run_stage("eval", params, inputs, work)

    return json.loads(project.path("eval", "report.json").read_text())
