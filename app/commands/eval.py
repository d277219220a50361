"""``dng eval PROJECT [--json]``: score the renderer and the baselines on unseen motions.

``dng eval joint2coarse PROJECT --motion FILE|KIND [--frames N] [--start-s S] [--json]``:
Joint2Coarse against the simulation on any motion."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from core.errors import InputError
from core.project import Project
from pipeline.config import available_test_motions, project_config, renderer_validation_motion
from pipeline.joint2coarse_eval import eval_motion, evaluate_on_motion, format_report
from pipeline.stages.ablations import check_ablation, stage_ablation
from pipeline.stages.dataset import stage_testset
from pipeline.stages.evaluate import ours_to_dnr, stage_eval
from pipeline.stages.simulate import stage_simulate


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "eval",
        help="score the neural renderer against the baselines on unseen motions and cameras",
        description=(
            "Render the project's validation motion (protocol V, where settings are chosen), "
            "every test motion (protocol U) and its training motion (protocol P, the paper's), "
            "each from unseen cameras, with our renderer (on "
            "Joint2Coarse's proxy, and on the simulated proxy) and every trained baseline; "
            "report per-frame MSE (mean and std, pixel values in [0, 1]), PSNR, SSIM, their "
            "garment-region versions, the garment's GMSD, mean gradient-similarity deficit and "
            "detail ratio, flicker, tOF, FID / "
            "video FID when an InceptionV3 weights file is given and tLP when an LPIPS weights "
            "file is given. Writes PROJECT/eval/report.json and PROJECT/eval/MOTION/compare.png. "
            "Builds the "
            "test sets first when they are missing; the renderer and baselines must be trained "
            "(dng train renderer|baselines PROJECT)."
        ),
    )
    p.add_argument(
        "project",
        help="project folder (made by dng demo); or the word joint2coarse, then the project: "
        "Joint2Coarse against the simulation on --motion",
    )
    p.add_argument("j2c_project", nargs="?", metavar="PROJECT", help=argparse.SUPPRESS)
    j = p.add_argument_group(
        "dng eval joint2coarse PROJECT",
        "retarget a motion onto the project's body, simulate the proxy with the project's "
        "fabric, substeps and fps (cached outside the project, in $XDG_CACHE_HOME/garment-studio "
        "or ~/.cache/garment-studio), run Joint2Coarse on it and report vertex error (mean, "
        "p95, max, mm), body penetration, stretch and the hem's radius of both, and ms per frame",
    )
    j.add_argument(
        "--motion",
        metavar="FILE|KIND",
        help="a motion file (BVH, glTF/GLB, DeepMimic .txt) or a procedural kind",
    )
    j.add_argument("--frames", type=int, help="frames to keep (default: all; 150 of a kind)")
    j.add_argument("--start-s", type=float, default=0.0, help="seconds of the file to skip")
    j.add_argument("--seed", type=int, default=0, help="seed of a procedural kind")
    j.add_argument(
        "--floor", action="store_true",
        help="also simulate the proxy moved 10 um at random: how far the simulation is from "
        "itself, which no prediction can be expected to beat (cached too)",
    )  # fmt: skip
    j.add_argument(
        "--realisations", type=int, default=None, metavar="N",
        help="also simulate the proxy N more times, each moved 10 um at random by offsets of "
        "its own (the first is --floor's), and score every model against each of the N + 1: "
        "how much a figure against one simulation is a draw; from N = 2, the mean of the other "
        "simulations against each too, about the best a prediction can do (cached too)",
    )  # fmt: skip
    p.add_argument(
        "--inception",
        metavar="WEIGHTS.pth",
        help="torchvision InceptionV3 weights (inception_v3_google-*.pth) for FID",
    )
    p.add_argument(
        "--lpips",
        metavar="WEIGHTS.pth",
        help="the lpips package's AlexNet weights (torch.save(lpips.LPIPS(net='alex')"
        ".state_dict(), FILE)) for tLP",
    )
    p.add_argument(
        "--ablations",
        nargs="+",
        metavar="NAME",
        help="train and score ablations too: no-motion, no-temporal (no SPADE conditioning on "
        "frame t-1, a single-frame discriminator), views-N (N cameras per frame), "
        "template-NAME (a coarse template as proxy, e.g. template-long-skirt); each costs about "
        "one renderer training",
    )
    p.add_argument("--json", action="store_true", help="print the whole report as JSON")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if args.project == "joint2coarse" and args.j2c_project is not None:
        return run_joint2coarse(args)

    if args.j2c_project is not None or args.motion is not None:
        raise InputError(
            "--motion and a second folder go with dng eval joint2coarse PROJECT --motion M"
        )
    return run_renderers(args)


def run_joint2coarse(args: argparse.Namespace) -> int:

    if args.motion is None:
        raise InputError("dng eval joint2coarse needs --motion FILE or a procedural kind")
    project = Project(args.j2c_project)
    config = project_config(project)
    log = (lambda message: print(message, file=sys.stderr, flush=True)) if args.json else print
    motion = eval_motion(config, args.motion, args.frames, args.start_s, args.seed)
    if args.realisations is not None and args.realisations < 1:
        raise InputError(f"--realisations must be at least 1, got {args.realisations}")
    report = evaluate_on_motion(
        project, config, motion, args.motion, log, floor=args.floor,
        realisations=args.realisations or 0,
    )  # fmt: skip
    print(json.dumps(report, indent=1) if args.json else format_report(report))
    return 0


def _print_table(methods: dict) -> None:
    """One line per method: garment-region MSE, full-frame MSE (mean ± std), PSNR, SSIM,
    flicker."""
    print(
        f"{'method':44s} {'MSE garment':>12s} {'MSE':>16s} {'PSNR':>7s} {'SSIM':>7s} {'flicker':>8s}"
    )
    for name, m in methods.items():
        print(
            f"{name:44s} {m['mse_masked']['mean']:12.4f} {m['mse']['mean']:.4f} ± "
            f"{m['mse']['std']:.4f} {m['psnr']['mean']:7.2f} {m['ssim']['mean']:7.4f} "
            f"{m['flicker']['mean']:8.4f}"
        )


def _print_ratios(methods: dict, indent: str) -> None:
    """Ours / DNR (``ours_to_dnr``, from the methods' figures: an eval report reused from before
    the garment-region ratios has them too): the garment region first, then full frame, on
    Joint2Coarse's proxy and on the simulated one."""
    ratios = ours_to_dnr(methods)
    for metric, what in (("mse_masked", "garment-region MSE"), ("mse", "MSE")):
        for suffix, proxy in (
            ("", "Joint2Coarse's proxy"),
            ("_simulated_proxy", "the simulated proxy"),
        ):
            key = f"{metric}_ratio_ours_to_dnr{suffix}"
            if key in ratios:
                print(f"{indent}{what} ours / DNR, on {proxy}: {ratios[key]:.2f}")


def run_renderers(args: argparse.Namespace) -> int:

    project = Project(args.project)
    config = project_config(project)
    if args.inception:
        path = Path(args.inception)
        if not path.is_file():
            raise InputError("Inception weights file not found", path)
        config = replace(config, inception_path=str(path.resolve()))
    if args.lpips:
        path = Path(args.lpips)
        if not path.is_file():
            raise InputError("LPIPS weights file not found", path)
        config = replace(config, lpips_path=str(path.resolve()))
    if args.ablations:
        config = replace(config, ablations=tuple(args.ablations))
        for name in config.ablations:
            check_ablation(name)
        settings = project.settings()
        settings["pipeline"] = config.as_params()
        project.save_settings(settings)  # the next dng eval (and the demo) keep them
    # With --json, stdout carries only the report (a pipeline parses it); progress goes to stderr.
    log = (lambda message: print(message, file=sys.stderr, flush=True)) if args.json else print
    validation = renderer_validation_motion(config)
    if validation:  # protocol V: where the settings are chosen
        stage_simulate(project, config, validation.name, "target", log)
        stage_testset(project, config, validation.name, log, validation=True)
    for m in available_test_motions(config):
        stage_simulate(project, config, m.name, "target", log)
        stage_testset(project, config, m.name, log)
    stage_testset(project, config, config.train_motion.name, log)  # protocol P
    for name in config.ablations:
        stage_ablation(project, config, name, log)
    report = stage_eval(project, config, log)
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    v = report.get("validation")
    if v:
        print(f"protocol V ({v['motion']}, the validation motion, cameras of its own):")
        _print_table(v["methods"])
        _print_ratios(v["methods"], "")
        print("protocol U (the test motions, unseen cameras):")
    _print_table(report["methods"])
    _print_ratios(report["methods"], "")
    p = report.get("protocol_p")
    if p:
        print(f"protocol P ({p['motion']}, the training motion, unseen cameras):")
        _print_ratios(p["methods"], "  ")
    print(f"report: {project.path('eval', 'report.json')}")
    return 0
