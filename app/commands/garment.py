"""``dng garment``: list the built-in garments, make one fitted to a body shape."""

from __future__ import annotations

import argparse
from pathlib import Path

from core.body.shape import BodyShape
from core.errors import InputError
from core.mesh import MESH_SUFFIXES, save_mesh
from templates.garments import DEFAULT_TARGET, GARMENTS, build_garment


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "garment",
        help="built-in garments: detailed targets and coarse templates",
        description="List the built-in garments or make one, fitted to a body shape at rest.",
    )
    actions = parser.add_subparsers(dest="garment_action", metavar="ACTION")
    actions.required = True

    make = actions.add_parser(
        "make",
        help="make a built-in garment and save it as a mesh",
        description="Make a built-in garment fitted to the mannequin and save it.",
    )
    make.add_argument("name", help="garment name (see `dng garment list`)")
    make.add_argument(
        "--resolution",
        type=float,
        default=None,
        metavar="MM",
        help="target edge length in millimetres (default: the garment's own)",
    )
    make.add_argument(
        "--shape",
        nargs="+",
        default=None,
        metavar="K=V",
        help="body shape parameters, e.g. height=1.8 build=0.5",
    )
    make.add_argument("--seed", type=int, default=0, help="seed for the folds' irregularity")
    make.add_argument("--out", required=True, help="output mesh (.obj, .ply, .glb, .off, .stl)")
    make.set_defaults(handler=_make)

    lister = actions.add_parser("list", help="list the built-in garments")
    lister.set_defaults(handler=_list)


def _make(args: argparse.Namespace) -> int:

    out = Path(args.out)
    writable = tuple(s for s in MESH_SUFFIXES if s != ".gltf")
    if out.suffix.lower() not in writable:
        raise InputError(
            f"cannot write {out.suffix or 'no extension'!r}; use one of {', '.join(writable)}", out
        )
    shape = BodyShape.parse(args.shape)
    garment = build_garment(args.name, args.resolution, shape, args.seed)
    save_mesh(out, garment.mesh)
    mesh = garment.mesh
    print(
        f"{garment.name}: {mesh.num_vertices} vertices, {mesh.num_faces} faces, "
        f"{len(garment.parts)} parts ({', '.join(garment.parts)}), "
        f"{garment.num_components} components, resolution {garment.resolution_mm:g} mm -> {out}"
    )
    return 0


def _list(args: argparse.Namespace) -> int:

    for name, spec in GARMENTS.items():
        lo, hi = spec.resolution_range_mm
        default = " (default target)" if name == DEFAULT_TARGET else ""
        print(
            f"{name:18s} {spec.kind:8s} {spec.resolution_mm:4g} mm [{lo:g}-{hi:g}]  "
            f"{spec.description}{default}"
        )
    return 0
