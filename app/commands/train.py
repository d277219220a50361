"""``dng train joint2coarse PROJECT``: train a project's networks."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train a project's networks")
    what = p.add_subparsers(dest="network", metavar="NETWORK")
    what.required = True
    j = what.add_parser(
        "joint2coarse",
        help="body motion -> coarse proxy, from the project's proxy simulation",
        description=(
            "Train Joint2Coarse on the training motion's simulated proxy (resuming an "
            "interrupted run), then predict and measure every test motion against its "
            "simulation: per-vertex error (mean, 95th percentile, mm) and body penetration, "
            "written to PROJECT/joint2coarse/report.json."
        ),
    )
    j.add_argument("project", help="project folder (made by dng demo)")
    j.add_argument("--preset", help="Joint2Coarse preset (paper, fast); default: the project's")
    j.set_defaults(handler=run_joint2coarse)


def run_joint2coarse(args: argparse.Namespace) -> int:
    import json
    from dataclasses import replace

    from core.project import Project
    from training.pipeline import project_config, stage_joint2coarse

    project = Project(args.project)
    config = project_config(project)
    if args.preset:
        config = replace(config, joint2coarse_preset=args.preset, joint2coarse_steps=None)
    report = stage_joint2coarse(project, config, print)
    print(json.dumps(report["motions"], indent=1))
    return 0
