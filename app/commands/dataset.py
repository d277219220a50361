"""``dng dataset PROJECT``: ground-truth renders and cameras for the neural renderer."""

from __future__ import annotations

import argparse
from dataclasses import replace

from core.errors import InputError
from core.project import Project
from pipeline.config import project_config
from pipeline.stages.dataset import stage_dataset
from training.dataset import GarmentDataset


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "dataset",
        help="build a project's training set (ground-truth images, backgrounds, cameras)",
        description=(
            "Render the simulated target on the body and the body alone from random cameras "
            "around it, for samples of frames t-1, t, t+1 of the training motion. Feature maps "
            "are rasterized on the fly at training time, so only PNGs and cameras are stored."
        ),
    )
    p.add_argument("project", help="project folder (made by dng demo)")
    p.add_argument("--views", type=int, help="cameras per sample frame (default: the project's)")
    p.add_argument("--size", type=int, help="image size in pixels (default: the project's)")
    p.add_argument("--stride", type=int, help="frames between sample centres")
    p.add_argument(
        "--sheet", metavar="PNG", help="also write a contact sheet of the first sample here"
    )
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:

    project = Project(args.project)
    config = project_config(project)
    updates = {
        "views_per_frame": args.views,
        "image_size": args.size,
        "frame_stride": args.stride,
    }
    for key, value in updates.items():
        if value is not None and value < 1:
            raise InputError(f"--{key} must be at least 1, got {value}")
    config = replace(config, **{k: v for k, v in updates.items() if v is not None})
    out = stage_dataset(project, config, print)
    print(f"data set: {out}")
    if args.sheet:
        GarmentDataset(project.root).contact_sheet(0, args.sheet)
        print(f"contact sheet: {args.sheet}")
    return 0
