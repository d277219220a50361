"""``dng train joint2coarse|renderer|baselines PROJECT``: train a project's networks."""

from __future__ import annotations

import argparse
import json
from dataclasses import replace

from app.commands import parse_setting
from core.errors import InputError
from core.project import Project
from pipeline.config import baseline_config, joint2coarse_config, project_config, renderer_config
from pipeline.stages.baselines import stage_baselines
from pipeline.stages.joint2coarse import stage_joint2coarse
from pipeline.stages.renderer import stage_renderer


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train a project's networks")
    what = p.add_subparsers(dest="network", metavar="NETWORK")
    what.required = True
    j = what.add_parser(
        "joint2coarse",
        help="body motion -> coarse proxy, from the project's proxy simulation",
        description=(
            "Train Joint2Coarse on its training split's simulated proxies (resuming an "
            "interrupted run), then predict and measure every validation and test motion "
            "against its simulation: per-vertex error (mean, 95th percentile, mm) and body "
            "penetration of the prediction and the simulation, written to "
            "PROJECT/joint2coarse/report.json. --set model=paper|ours picks the model; the "
            "project's joint2coarse_compare models train beside it on the same splits."
        ),
    )
    j.add_argument("project", help="project folder (made by dng demo)")
    j.add_argument("--preset", help="Joint2Coarse preset (paper, fast); default: the project's")
    _add_set(j, "Joint2Coarse", "--set dropout=0.2 --set window=16")
    j.set_defaults(handler=run_joint2coarse)
    r = what.add_parser(
        "renderer",
        help="the neural renderer, on the project's data set",
        description=(
            "Train the neural renderer on PROJECT/dataset (resuming an interrupted run): "
            "PROJECT/renderer/ gets renderer.pt, the CSV loss log, loss.png (loss curves), "
            "previews/ (prediction | ground truth) and report.json."
        ),
    )
    r.add_argument("project", help="project folder (made by dng demo)")
    r.add_argument("--preset", help="renderer preset (tiny, cpu, paper); default: the project's")
    r.add_argument(
        "--steps",
        type=int,
        help="optimisation steps (default: the project's renderer_steps, else the preset's)",
    )
    r.add_argument(
        "--source",
        choices=("sim", "joint2coarse"),
        help="proxy to train on: simulated or Joint2Coarse's prediction (default: the "
        "project's renderer_source; quick and smoke train on Joint2Coarse's)",
    )
    _add_workers(r)
    _add_set(r, "renderer", "--set w_gan=0 --set w_fm=0")
    r.set_defaults(handler=run_renderer)
    b = what.add_parser(
        "baselines",
        help="Pix2Pix and Deferred Neural Rendering on the same data set (for dng eval)",
        description=(
            "Train the comparison baselines on PROJECT/dataset with as many steps as the "
            "renderer: PROJECT/baselines/KIND/."
        ),
    )
    b.add_argument("project", help="project folder (made by dng demo)")
    b.add_argument("--kinds", nargs="+", help="baselines to train (default: the project's)")
    _add_workers(b)
    _add_set(b, "baseline", "--set lr_decay_from=0.5")
    b.set_defaults(handler=run_baselines)


def _add_workers(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--workers",
        type=int,
        help=(
            "DataLoader worker processes loading batches ahead, for this run (default: the "
            "project's loader_workers, 0); the trained weights are the same for any count"
        ),
    )


def _add_set(parser: argparse.ArgumentParser, what: str, example: str) -> None:
    parser.add_argument(
        "--print-config",
        action="store_true",
        help=(
            f"print the {what} configuration this command would train with (the preset, the "
            "project's settings and this command's changes, resolved) as JSON, and stop: "
            "nothing is trained or saved"
        ),
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        metavar="KEY=VALUE",
        help=(
            f"change one {what} setting from the preset, e.g. {example} (values read as "
            "JSON: numbers, true/false, lists); kept in the project's settings"
        ),
    )


def _print_config(args: argparse.Namespace, config, network: str) -> bool:
    """With ``--print-config``: print the resolved configuration(s) as JSON; True if printed."""
    if not args.print_config:
        return False
    if network == "renderer":
        resolved = renderer_config(config).to_dict()
    elif network == "joint2coarse":
        resolved = joint2coarse_config(config).to_dict()
    else:
        resolved = {kind: baseline_config(config, kind).to_dict() for kind in config.baselines}
    print(json.dumps(resolved, indent=1))
    return True


def run_joint2coarse(args: argparse.Namespace) -> int:

    project, config = _config_with(args, "joint2coarse")
    if _print_config(args, config, "joint2coarse"):
        return 0
    report = stage_joint2coarse(project, config, print)
    keys = ("model", "splits", "validation_motions", "motions", "compare")
    print(json.dumps({k: report[k] for k in keys if k in report}, indent=1))
    return 0


def _config_with(args: argparse.Namespace, network: str = "renderer"):
    """The project and its settings with this command's changes; saved when there are any.

    ``network`` (``renderer``, ``joint2coarse`` or ``baseline``) is what ``--preset`` and
    ``--set`` change.
    """
    project = Project(args.project)
    config = project_config(project)
    changes = {}
    if getattr(args, "preset", None):
        changes[f"{network}_preset"] = args.preset
        if network == "joint2coarse":
            changes["joint2coarse_steps"] = None  # the preset's own schedule
    if getattr(args, "steps", None) is not None:
        changes["renderer_steps"] = args.steps
    if getattr(args, "source", None):
        changes["renderer_source"] = args.source
    if getattr(args, "kinds", None):
        changes["baselines"] = tuple(args.kinds)
    if getattr(args, "overrides", None):
        changes[f"{network}_overrides"] = {
            **getattr(config, f"{network}_overrides"),
            **dict(parse_setting(item) for item in args.overrides),
        }
    config = replace(config, **changes)

    # an unknown preset, kind or setting fails here, before the settings change
    joint2coarse_config(config)
    renderer_config(config)
    for kind in config.baselines:
        baseline_config(config, kind)
    if getattr(args, "print_config", False):
        return project, config
    if changes:  # later stages (dng eval, the GUI) read the same settings
        settings = project.settings()
        settings["pipeline"] = config.as_params()
        project.save_settings(settings)
    return project, config


def _with_workers(args: argparse.Namespace, project, config):
    """``--workers`` for this run only (a property of the machine, not kept in the project)."""
    if args.workers is None:
        return project, config
    if args.workers < 0:
        raise InputError(f"--workers must be at least 0, got {args.workers}")
    return project, replace(config, loader_workers=args.workers)


def run_renderer(args: argparse.Namespace) -> int:

    project, config = _with_workers(args, *_config_with(args))
    if _print_config(args, config, "renderer"):
        return 0
    report = stage_renderer(project, config, print)
    keep = ("steps", "seconds_per_step", "skipped_steps", "perceptual", "first", "last")
    print(json.dumps({k: report[k] for k in keep}, indent=1))
    print(f"model: {project.path('renderer', 'renderer.pt')}")
    return 0


def run_baselines(args: argparse.Namespace) -> int:

    project, config = _with_workers(args, *_config_with(args, "baseline"))
    if _print_config(args, config, "baseline"):
        return 0
    reports = stage_baselines(project, config, print)
    print(json.dumps({k: {"steps": r["steps"], "seconds_per_step": r["seconds_per_step"]}
                      for k, r in reports.items()}, indent=1))  # fmt: skip
    return 0
