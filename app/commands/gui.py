"""``dng gui [PROJECT]``: the studio window (Open3D)."""

from __future__ import annotations

import argparse
import os

from app.gui import run as run_gui
from app.gui.tour import run_tour
from core.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "gui",
        help="open the studio window (garment, proxy, motion playback, live neural render)",
        description=(
            "Open the garment studio window: load a detailed garment and derive its proxy with "
            "sliders; play motions through a trained project (Joint2Coarse) with a live neural "
            "render of the 3D view's camera; run simulation, data building and training with "
            "progress; export GIFs and the proxy. Window settings and the camera path are saved "
            'in PROJECT/project.json under "gui".'
        ),
    )
    p.add_argument("project", nargs="?", help="project folder (made by dng demo)")
    p.add_argument("--size", default="1500x940", metavar="WxH", help="window size in pixels")
    p.add_argument(
        "--play", action="store_true",
        help="start playing PROJECT's motion as soon as it is loaded (no input needed)",
    )  # fmt: skip
    p.add_argument(
        "--tour", metavar="DIR",
        help="drive the main flow automatically, save screenshots and timings into DIR, exit",
    )  # fmt: skip
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:

    try:
        width, height = (int(x) for x in args.size.lower().split("x"))
    except ValueError:
        raise InputError(f"--size must be WIDTHxHEIGHT, got {args.size!r}") from None
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        raise InputError("no display: set DISPLAY (for example run under xvfb-run)")
    if args.tour:
        if not args.project:
            raise InputError("--tour needs a trained PROJECT")
        return run_tour(args.project, args.tour, width=width, height=height)

    if args.play and not args.project:
        raise InputError("--play needs a trained PROJECT")
    return run_gui(args.project, width=width, height=height, play=args.play)
