"""``dng motion``: inspect motion files (BVH, glTF/GLB, DeepMimic), make procedural clips,
retarget onto the mannequin."""

from __future__ import annotations

import argparse
import json
import math

from core.body.shape import BodyShape
from core.errors import InputError
from core.motion.bvh import write_bvh
from core.motion.mapping import canonical_positions
from core.motion.procedural import PROCEDURAL_KINDS, make_motion
from core.motion.retarget import retarget


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "motion",
        help="inspect, make and retarget body motion (BVH, glTF/GLB, DeepMimic in)",
        description="Body motion: BVH, skinned glTF/GLB and DeepMimic (.txt/.json) import (any "
        "rig, units, up axis), procedural clips, retargeting onto the mannequin.",
    )
    sub = parser.add_subparsers(dest="motion_command", metavar="ACTION")
    sub.required = True

    info = sub.add_parser("info", help="what a motion file holds, mapped onto the canonical joints")
    info.add_argument("file", help=_FILE_HELP)
    info.add_argument("--json", action="store_true", help="print JSON instead of text")
    _add_import_options(info)
    info.set_defaults(handler=_info)

    make = sub.add_parser("make", help="make a procedural clip on the mannequin and write BVH")
    make.add_argument("kind", help="clip kind (see core.motion.procedural.PROCEDURAL_KINDS)")
    make.add_argument("--frames", type=int, required=True, help="number of frames")
    make.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    make.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    make.add_argument("--out", required=True, help="BVH file to write")
    _add_shape_option(make)
    make.set_defaults(handler=_make)

    retarget = sub.add_parser("retarget", help="retarget a motion file onto the mannequin")
    retarget.add_argument("file", help=_FILE_HELP)
    retarget.add_argument("--out", required=True, help="BVH file to write")
    retarget.add_argument("--fps", type=float, default=None, help="resample to this frame rate")
    retarget.add_argument(
        "--floor",
        default="auto",
        metavar="auto|none|HEIGHT",
        help="the source's floor: auto (default: the lowest ankle height several frames reach; "
        "a frame or two lower is reported and stands on it), none (y = 0 of the file), or a "
        "height in metres in the file's frame after unit conversion",
    )
    _add_shape_option(retarget)
    _add_import_options(retarget)
    retarget.set_defaults(handler=_retarget)


_FILE_HELP = (
    "BVH file, a skinned .gltf/.glb with an animation, or a DeepMimic motion (.txt/.json, as "
    "pybullet_data/data/motions holds)"
)


def _add_import_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--mapping", default=None, help="JSON {canonical_name: source_name} for unusual rigs"
    )
    p.add_argument(
        "--scale", type=float, default=None, help="metres per file unit (overrides detection)"
    )
    p.add_argument(
        "--repeat",
        type=int,
        default=1,
        metavar="N",
        help="play a looping DeepMimic clip ('Loop': 'wrap') N times, each from where the last "
        "ended (default 1)",
    )


def _add_shape_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--shape",
        nargs="*",
        default=[],
        metavar="K=V",
        help="body shape, e.g. height=1.8 build=0.3 (core.body.shape.BodyShape fields)",
    )


def _info(args: argparse.Namespace) -> int:
    from core.motion.load import load_motion, motion_info

    motion = load_motion(args.file, scale=args.scale, mapping=args.mapping, repeat=args.repeat)
    info = motion_info(motion)
    info["file"] = str(args.file)
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    print(format_info(info))
    return 0


def format_info(info: dict) -> str:
    """The human-readable ``dng motion info`` report."""
    scale = info["unit_scale"]
    lines = [
        f"file:            {info['file']}",
        f"frames:          {info['frames']} at {info['fps']:g} fps ({info['duration_s']:.2f} s)",
        f"rig:             {info['rig']} ({info['num_source_joints']} joints)",
        f"up axis:         {info['up_axis'].upper()}"
        + (" (converted to Y up)" if info["up_axis"] != "y" else ""),
        f"unit:            {info['unit']} ({scale:.6g} m per file unit)",
        f"standing height: {info['standing_height_m']:.3f} m",
        f"root travel:     {info['root_path_length_m']:.3f} m path, "
        f"{info['root_displacement_m']:.3f} m net",
        f"root:            Hips <- {info['root']}",
        *([format_floor(info["floor"])] if info.get("floor") else []),
        "joints:",
    ]
    width = max(len(c) for c in info["joints"])
    lines += [f"  {c:<{width}} <- {s}" for c, s in info["joints"].items()]
    if info.get("varying_translations_m"):
        moved = ", ".join(
            f"{k} ({v * 100:.2f} cm)" for k, v in info["varying_translations_m"].items()
        )
        lines.append(f"note: varying joint translations replaced by their mean: {moved}")
    if info.get("wrapper_joints"):
        lines.append(
            f"note: wrapper joints above the root folded into it: {', '.join(info['wrapper_joints'])}"
        )
    if info.get("deepmimic"):
        dm = info["deepmimic"]
        lines.append(
            f"note: DeepMimic humanoid, loop {dm['loop']}"
            + (f", played {dm['repeat']} times" if dm["repeat"] > 1 else "")
        )
    lines.append("source joints:   " + ", ".join(info["source_joints"]))
    return "\n".join(lines)


def _make(args: argparse.Namespace) -> int:

    if args.kind not in PROCEDURAL_KINDS:
        raise InputError(f"unknown motion kind {args.kind!r}; choose from {list(PROCEDURAL_KINDS)}")
    if args.frames < 1:
        raise InputError(f"--frames must be at least 1, got {args.frames}")
    if not (math.isfinite(args.fps) and args.fps > 0):
        raise InputError(f"--fps must be positive, got {args.fps}")
    shape = BodyShape.parse(args.shape)
    motion = make_motion(args.kind, args.frames, args.fps, args.seed, shape)
    write_bvh(args.out, motion)
    print(f"wrote {args.out}: {motion.num_frames} frames at {motion.fps:g} fps ({args.kind})")
    return 0


def parse_floor(text: str) -> str | float:
    """``--floor``: ``auto``, ``none`` or a finite height in metres."""
    if text in ("auto", "none"):
        return text
    try:
        height = float(text)
    except ValueError:
        height = math.nan
    if not math.isfinite(height):
        raise InputError(f"--floor must be auto, none or a height in metres, got {text!r}")
    return height


def _retarget(args: argparse.Namespace) -> int:
    from core.motion.load import load_motion

    floor = parse_floor(args.floor)
    shape = BodyShape.parse(args.shape)
    motion = load_motion(
        args.file, fps=args.fps, scale=args.scale, mapping=args.mapping, repeat=args.repeat
    )
    positions = canonical_positions(motion)

    out = retarget(positions, motion.fps, shape, name=motion.name, floor=floor)
    write_bvh(args.out, out)
    print(
        f"wrote {args.out}: {out.num_frames} frames at {out.fps:g} fps, "
        f"retargeted from {motion.meta.get('rig', 'unknown')} rig "
        f"({motion.meta.get('unit')}, {motion.meta.get('up_axis', 'y').upper()} up)"
    )
    print(format_floor(out.meta["floor"], "mannequin"))
    return 0


def format_floor(floor: dict, depth_of: str = "source") -> str:
    """One or two lines on the floor: its height, how it was found, the contacts as frame
    ranges and the frames below it (depth in the ``depth_of`` clip's metres)."""
    ranges = ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in floor["contact_ranges"])
    if len(ranges) > 70:
        ranges = ranges[:67] + "..."
    how = {"support": "estimated", "given": "given", "none": "the file's y = 0"}[floor["method"]]
    text = (
        f"floor:           {floor['height_m']:.3f} m in the source ({how}); "
        f"{floor['contact_frames']} contact frames: {ranges or 'none'}"
    )
    below = floor["below_frames"]
    if below:
        shown = ", ".join(str(f) for f in below[:10]) + (", ..." if len(below) > 10 else "")
        text += (
            f"\nwarning:         {len(below)} frames with a foot below the floor (deepest "
            f"{100 * floor['below_deepest_m']:.1f} cm, {depth_of}): {shown}; they stand on it"
        )
    return text
