"""``dng proxy``: derive the coarse proxy of a target garment (detail removal, decimation, UVs)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from core.errors import InputError
from core.fileio import write_json, write_npz
from core.mesh import load_mesh, save_mesh
from core.proxy import derive_proxy
from core.proxy.config import LAYER_MODES, UNITS_M, ProxyConfig


def register(subparsers) -> None:

    d = ProxyConfig()
    p = subparsers.add_parser(
        "proxy",
        help="derive a coarse proxy with a UV atlas from a detailed garment",
        description=(
            "Derive the coarse proxy of TARGET: drop small parts, collapse stacked layers into one "
            "outer surface, smooth small folds, decimate, unwrap with xatlas. Writes the proxy "
            "(OBJ with UVs), a JSON report beside it and the target->proxy correspondence (.npz)."
        ),
    )
    p.add_argument("target", metavar="TARGET", help="detailed garment mesh (OBJ/PLY/GLB/...)")
    p.add_argument("--out", required=True, metavar="PROXY.obj", help="proxy mesh to write")
    p.add_argument("--target-verts", type=int, default=d.target_verts, metavar="N")
    p.add_argument(
        "--detail-scale", type=float, default=d.detail_scale, metavar="M",
        help=f"metres; folds narrower than this are smoothed away (default {d.detail_scale})",
    )  # fmt: skip
    p.add_argument("--texture-size", type=int, default=d.texture_size, metavar="PX")
    p.add_argument("--padding", type=int, default=d.padding, metavar="PX")
    p.add_argument(
        "--min-part", type=float, default=d.min_component_fraction, metavar="FRACTION",
        help="drop parts smaller than this fraction of the largest part's area",
    )  # fmt: skip
    p.add_argument(
        "--layers", choices=LAYER_MODES, default=d.layers,
        help="envelope: stacked layers become their outer surface; keep: the surface as it is; "
        "auto (default): the envelope only when layers are stacked (single-layer garments keep)",
    )  # fmt: skip
    p.add_argument("--unit", choices=("auto", *UNITS_M), default=d.unit)
    p.add_argument(
        "--template", metavar="NAME",
        help="fit a built-in coarse template (e.g. long-skirt) instead of deriving a proxy",
    )  # fmt: skip
    p.add_argument("--report", metavar="REPORT.json", help="default: PROXY.json")
    p.add_argument("--json", action="store_true", help="print the report as JSON on stdout")
    p.set_defaults(handler=run)


def load_template(name: str) -> object:
    """The built-in coarse template ``name`` (a :class:`core.mesh.Mesh`), or ``InputError``."""
    try:
        from templates.garments import make_garment
    except ImportError:
        raise InputError(f"template {name!r}: built-in templates are not installed") from None
    try:
        return make_garment(name)
    except (KeyError, ValueError) as exc:
        raise InputError(f"unknown template {name!r}: {exc}") from None


def run(args: argparse.Namespace) -> int:

    config = ProxyConfig(
        target_verts=args.target_verts,
        detail_scale=args.detail_scale,
        texture_size=args.texture_size,
        padding=args.padding,
        min_component_fraction=args.min_part,
        layers=args.layers,
        unit=args.unit,
    )
    out = Path(args.out)
    if out.suffix.lower() not in (".obj", ".ply", ".glb", ".gltf", ".off"):
        raise InputError("proxy must be written as .obj (or .ply/.glb/.gltf/.off)", out)
    target, repair = load_mesh(args.target)
    template = load_template(args.template) if args.template else None
    result = derive_proxy(target, config, path=args.target, template=template)
    report = result.report
    report["target"]["repair"] = repair.as_dict()
    if template is not None:
        report["template"] = args.template
    report_path = Path(args.report) if args.report else out.with_suffix(".json")
    corr_path = out.with_suffix(".corr.npz")
    report["files"] = {
        "proxy": str(out),
        "report": str(report_path),
        "correspondence": str(corr_path),
    }
    save_mesh(out, result.proxy)
    c = result.correspondence
    write_npz(
        corr_path,
        face=c.face,
        barycentric=c.barycentric,
        distance=c.distance,
        seam_map=result.seam_map,
        positions=result.positions.vertices,
        position_faces=result.positions.faces,
        target_scale=np.float64(result.target_scale),
    )
    write_json(report_path, report)
    if args.json:
        print(json.dumps(report, indent=2, default=float))
    else:
        r, dist, uv = report["proxy"], report["distance"], report["uv"]
        print(
            f"proxy {out}: {r['vertices']} vertices, {r['faces']} faces, {r['components']} "
            f"part(s), {r['boundary_loops']} boundary loop(s), layers={report['layers']['used']}; "
            f"Hausdorff {dist['hausdorff_m'] * 1000:.1f} mm ({dist['hausdorff_rel']:.2%} of the "
            f"diagonal); UV {uv['charts']} charts, {uv['utilization']:.0%} used, "
            f"{uv['flipped']} flipped; {report['total_s']:.2f} s"
        )
        for note in report["notes"]:
            print(f"  note: {note}")
    return 0
