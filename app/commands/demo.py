"""``dng demo``: the main job end to end on the built-in assets, no files needed."""

from __future__ import annotations

import argparse

from pipeline.config import preset
from pipeline.demo import run_demo


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="run the main job on built-in assets (mannequin, dance, multi-layer skirt)",
        description=(
            "Run every stage on the built-in assets: procedural dance as training motion, the "
            "multi-layer skirt as target, unseen motions (a twirl, and real CMU motion capture "
            "when assimp-testmodels is installed) for evaluation. Writes DIR/report.md and "
            "DIR/report.json. Rerunning reuses finished stages."
        ),
    )
    p.add_argument(
        "--preset",
        default="quick",
        choices=["smoke", "quick", "paper"],
        help="smoke: minutes, for tests; quick (default): the 2-core default; paper: GPU sizes",
    )
    p.add_argument("--out", default="out/demo", help="project folder (default: out/demo)")
    p.add_argument("--force", action="store_true", help="rerun every stage")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:

    run_demo(preset(args.preset), args.out, preset_name=args.preset, force=args.force)
    return 0
