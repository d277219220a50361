"""``dng export torch PROJECT --out FILE``: a trained project in one file torch alone can render."""

from __future__ import annotations

import argparse
import os


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write a trained project in another form")
    what = p.add_subparsers(dest="form", metavar="FORM")
    what.required = True
    x = what.add_parser(
        "torch",
        help="a bundle for the torch-only render path (a GPU machine with only torch + numpy)",
        description=(
            "Write the project's Joint2Coarse, renderer, proxy, body and motions (posed on "
            "the mannequin) into one file that training.torchpath reads with torch alone."
        ),
    )
    x.add_argument("project", help="a trained project folder")
    x.add_argument("--out", required=True, help="bundle file to write (.pt)")
    x.add_argument(
        "--motion", nargs="+", default=None, metavar="M",
        help="BVH files, project motions or procedural kinds (default: the training motion)",
    )  # fmt: skip
    x.add_argument("--frames", type=int, default=None, help="first frames of each motion")
    x.add_argument(
        "--joint2coarse", default=None, metavar="FILE",
        help="another Joint2Coarse model file than the project's (paper or ours), e.g. "
        "PROJECT/joint2coarse/compare-ours/joint2coarse.pt",
    )  # fmt: skip
    x.set_defaults(handler=run_torch)


def run_torch(args: argparse.Namespace) -> int:

    from pipeline.torch_export import export_bundle

    bundle = export_bundle(
        args.project, args.out, args.motion, frames=args.frames, joint2coarse=args.joint2coarse
    )
    clips = ", ".join(f"{k} ({len(c['joints'])} frames)" for k, c in bundle["clips"].items())
    size = os.path.getsize(args.out) / 2**20
    print(f"wrote {args.out} ({size:.1f} MiB): clips {clips}")
    return 0
