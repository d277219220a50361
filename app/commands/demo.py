"""``dng demo``: the main job end to end, on the built-in assets or on a garment you give."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from core.errors import InputError
from core.lighting import PRESETS as PRESETS_OF_LIGHT
from core.lighting import load_lighting
from core.mesh import load_mesh
from pipeline.config import preset
from pipeline.demo import run_demo
from templates.garments import GARMENTS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="run the main job on built-in assets (mannequin, dance, multi-layer skirt)",
        description=(
            "Run every stage on the built-in assets: procedural dance as training motion, the "
            "multi-layer skirt as target, unseen motions (a twirl, and real CMU motion capture "
            "when assimp-testmodels is installed) for evaluation. Writes DIR/report.md and "
            "DIR/report.json. Rerunning reuses finished stages. --garment trains the project on "
            "your own detailed garment instead of the skirt."
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
    p.add_argument(
        "--garment", default=None, metavar="NAME|FILE",
        help="the detailed garment: a built-in name (`dng garment list`) or a mesh file (OBJ, "
        "PLY, GLB, OFF, STL) in metres, Y up, dressed on the mannequin (`dng body make`); "
        "default: the preset's multi-layer skirt",
    )  # fmt: skip
    p.add_argument(
        "--lighting", default=None, metavar="LIGHT",
        help="the light the data set, test sets and videos are rendered under: a preset "
        f"({', '.join(PRESETS_OF_LIGHT)}), an environment image (.hdr, .exr, .png, .jpg) or a "
        "lighting.json; default: studio",
    )  # fmt: skip
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:

    config = preset(args.preset)
    if args.garment is not None:
        config = dataclasses.replace(config, garment=_garment(args.garment))
    if args.lighting is not None:
        load_lighting(args.lighting)  # a bad light is refused now, not minutes into the run
        light = (
            args.lighting
            if args.lighting in PRESETS_OF_LIGHT
            else str(Path(args.lighting).resolve())
        )
        config = dataclasses.replace(config, lighting=light)
    run_demo(config, args.out, preset_name=args.preset, force=args.force)
    return 0


def _garment(value: str) -> str:
    """A built-in garment's name, or a mesh file's absolute path once it loads and validates
    (a bad file is refused now, not twenty minutes into the run)."""
    if not Path(value).suffix:
        if value not in GARMENTS:
            raise InputError(
                f"--garment {value!r}: no built-in garment of that name; "
                f"choose from {', '.join(sorted(GARMENTS))} or give a mesh file"
            )
        return value
    load_mesh(value)
    return str(Path(value).resolve())
