"""``dng body``: build the parametric mannequin, optionally posed at a frame of a motion."""

from __future__ import annotations

import argparse
from pathlib import Path

from core.body.mannequin import DEFAULT_RESOLUTION, make_body
from core.body.shape import BodyShape
from core.body.skinning import pose_body
from core.errors import InputError
from core.mesh import Mesh, save_mesh
from core.motion.mapping import canonical_positions
from core.motion.retarget import retarget

#: Mesh types ``dng body make`` writes.
BODY_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "body",
        help="build the mannequin body mesh (any shape, optionally posed)",
        description="The parametric mannequin: a closed, skinned body mesh for a body shape.",
    )
    sub = parser.add_subparsers(dest="body_command", metavar="ACTION")
    sub.required = True
    make = sub.add_parser("make", help="write the mannequin mesh, at rest or posed at a frame")
    make.add_argument(
        "--shape",
        nargs="*",
        default=[],
        metavar="K=V",
        help="body shape, e.g. height=1.8 hip=1.0 build=0.3 (core.body.shape.BodyShape fields)",
    )
    make.add_argument(
        "--resolution", type=int, default=None, help="target vertex count (default 9000)"
    )
    make.add_argument("--motion", default=None, help="BVH file: pose the body at --frame")
    make.add_argument("--frame", type=int, default=None, help="frame of --motion (from 0)")
    make.add_argument("--out", required=True, help=f"mesh file ({', '.join(BODY_SUFFIXES)})")
    make.set_defaults(handler=_make)


def _make(args: argparse.Namespace) -> int:

    out = Path(args.out)
    if out.suffix.lower() not in BODY_SUFFIXES:
        raise InputError(f"unsupported mesh type {out.suffix!r}; use {', '.join(BODY_SUFFIXES)}")
    if args.frame is not None and args.motion is None:
        raise InputError("--frame needs --motion")
    shape = BodyShape.parse(args.shape)
    resolution = DEFAULT_RESOLUTION if args.resolution is None else args.resolution
    motion = None
    if args.motion is not None:
        from core.motion.load import load_motion

        source = load_motion(args.motion)
        frame = 0 if args.frame is None else args.frame
        if not 0 <= frame < source.num_frames:
            raise InputError(
                f"frame {frame} is out of range: the clip has {source.num_frames} frames "
                f"(0..{source.num_frames - 1})",
                args.motion,
            )
        motion = retarget(canonical_positions(source), source.fps, shape, name=source.name)
    body = make_body(shape, resolution)
    vertices = body.vertices
    what = "rest pose"
    if motion is not None:
        r, p = motion.rotations[frame : frame + 1], motion.root_positions[frame : frame + 1]
        vertices = pose_body(body, (r, p))[0]
        what = f"frame {frame} of {args.motion}"
    save_mesh(out, Mesh(vertices, body.faces))
    girths = ", ".join(f"{k} {body.girth(k):.3f} m" for k in ("hip", "waist", "chest"))
    print(
        f"wrote {out}: {body.num_vertices} vertices, {len(body.faces)} faces, {what}; "
        f"girths {girths}"
    )
    return 0
