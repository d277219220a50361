"""``dng eval PROJECT [--json]``: score the renderer and the baselines on unseen motions."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "eval",
        help="score the neural renderer against the baselines on unseen motions and cameras",
        description=(
            "Render every test motion of the project from unseen cameras with our renderer "
            "(on Joint2Coarse's proxy, and on the simulated proxy) and every trained baseline; "
            "report per-frame MSE (mean and std, pixel values in [0, 1]), PSNR, SSIM, their "
            "garment-region versions, flicker, and FID / video FID when an InceptionV3 weights "
            "file is given. Writes PROJECT/eval/report.json and compare-MOTION.png. Builds the "
            "test sets first when they are missing; the renderer and baselines must be trained "
            "(dng train renderer|baselines PROJECT)."
        ),
    )
    p.add_argument("project", help="project folder (made by dng demo)")
    p.add_argument(
        "--inception",
        metavar="WEIGHTS.pth",
        help="torchvision InceptionV3 weights (inception_v3_google-*.pth) for FID",
    )
    p.add_argument(
        "--ablations",
        nargs="+",
        metavar="NAME",
        help="train and score ablations too: no-motion, views-N (N cameras per frame), "
        "template-NAME (a coarse template as proxy, e.g. template-long-skirt); each costs about "
        "one renderer training",
    )
    p.add_argument("--json", action="store_true", help="print the whole report as JSON")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    import json
    import sys
    from dataclasses import replace
    from pathlib import Path

    from core.errors import InputError
    from core.project import Project
    from training.pipeline import (
        available_test_motions,
        check_ablation,
        project_config,
        stage_ablation,
        stage_eval,
        stage_simulate,
        stage_testset,
    )

    project = Project(args.project)
    config = project_config(project)
    if args.inception:
        path = Path(args.inception)
        if not path.is_file():
            raise InputError("Inception weights file not found", path)
        config = replace(config, inception_path=str(path.resolve()))
    if args.ablations:
        config = replace(config, ablations=tuple(args.ablations))
        for name in config.ablations:
            check_ablation(name)
        settings = project.settings()
        settings["pipeline"] = config.as_params()
        project.save_settings(settings)  # the next dng eval (and the demo) keep them
    # With --json, stdout carries only the report (a pipeline parses it); progress goes to stderr.
    log = (lambda message: print(message, file=sys.stderr, flush=True)) if args.json else print
    for m in available_test_motions(config):
        stage_simulate(project, config, m.name, "target", log)
        stage_testset(project, config, m.name, log)
    for name in config.ablations:
        stage_ablation(project, config, name, log)
    report = stage_eval(project, config, log)
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    print(
        f"{'method':44s} {'MSE':>16s} {'PSNR':>7s} {'SSIM':>7s} {'MSE garment':>12s} {'flicker':>8s}"
    )
    for name, m in report["methods"].items():
        print(
            f"{name:44s} {m['mse']['mean']:.4f} ± {m['mse']['std']:.4f} {m['psnr']['mean']:7.2f} "
            f"{m['ssim']['mean']:7.4f} {m['mse_masked']['mean']:12.4f} {m['flicker']['mean']:8.4f}"
        )
    if "mse_ratio_ours_to_dnr" in report:
        print(f"MSE ours / DNR, on Joint2Coarse's proxy: {report['mse_ratio_ours_to_dnr']:.2f}")
    if "mse_ratio_ours_to_dnr_simulated_proxy" in report:
        ratio = report["mse_ratio_ours_to_dnr_simulated_proxy"]
        print(f"MSE ours / DNR, on the simulated proxy: {ratio:.2f}")
    print(f"report: {project.path('eval', 'report.json')}")
    return 0
