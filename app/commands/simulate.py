"""``dng simulate``: cloth simulation of a garment on the moving mannequin, or cache import.

Simulate::

    dng simulate --garment G.obj --motion M.bvh [--body-shape k=v ...] [--fabric silk]
                 [--substeps N] --out CACHE.npz [--json] [--preview [PNG]] [--export FILE ...]

``--garment`` is a mesh file or a built-in garment name; ``--motion`` a BVH file (retargeted
onto the mannequin) or a procedural kind (``dance``, ``twirl``...). Writes the cache and a JSON
report beside it (``CACHE.report.json``).

Embed a detailed garment in a simulated proxy instead (``core.sim.embed``; reports the
garment's edge stretch, compression and tears). With the proxy's ``--motion`` (and body), the
garment is also kept out of the body's capsules, as the pipeline's embedded target is, and the
report gives its penetration::

    dng simulate --garment TARGET.obj --embed-in PROXY.obj PROXY_CACHE.npz [--motion M.bvh
                 [--no-contact]] --out CACHE.npz

Import a cache simulated elsewhere (OBJ-sequence folder, ``.pc2``, ``.mdd``, ``.npz``)::

    dng simulate --import frames/ --garment G.obj --out CACHE.npz [--fps 30]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from app.commands import parse_setting
from core.body.colliders import penetration_depths, simulation_colliders
from core.body.mannequin import make_body
from core.body.shape import MANNEQUIN_JOINTS, BodyShape
from core.body.skinning import pose_body
from core.errors import InputError
from core.fileio import write_json
from core.mesh import MESH_SUFFIXES, load_mesh, weld_mesh
from core.motion.mapping import canonical_positions
from core.motion.procedural import make_motion
from core.motion.retarget import retarget
from core.sim.cache import (
    SimCache,
    export_cache,
    import_cache,
    load_cache,
    save_cache,
    unweld_cache,
)
from core.sim.config import QUALITY, SimConfig
from core.sim.preview import preview_sheet
from core.sim.thickness import layer_thickness
from templates.garments import make_garment


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="simulate a garment on the moving body (newton), or import a cache",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--garment", required=True, help="garment mesh file or built-in garment name")
    p.add_argument(
        "--motion",
        help="BVH, glTF/GLB or DeepMimic (.txt) file, or a procedural kind (dance, twirl, walk...)",
    )
    p.add_argument("--import", dest="import_from", metavar="CACHE", help="import this cache")
    p.add_argument(
        "--embed-in", nargs=2, metavar=("PROXY", "CACHE"),
        help="drive the garment by this proxy mesh's simulation (its cache) instead",
    )  # fmt: skip
    p.add_argument(
        "--layers", metavar="TARGET",
        help="the garment is this layered TARGET's proxy: keep each vertex off the body by the "
        "depth of TARGET's layers beneath it (as dng demo simulates a project's proxy)",
    )  # fmt: skip
    p.add_argument(
        "--no-contact", action="store_true",
        help="with --embed-in and --motion: measure the garment's penetration into the body "
        "but do not keep it out",
    )  # fmt: skip
    p.add_argument("--out", required=True, help="cache to write (.npz)")
    p.add_argument("--frames", type=int, default=150, help="procedural motion: frames (150)")
    p.add_argument("--fps", type=float, default=None, help="frame rate (procedural: 30)")
    p.add_argument("--seed", type=int, default=0, help="procedural motion seed (0)")
    p.add_argument(
        "--body-shape", "--shape", dest="shape", nargs="*", default=[], metavar="K=V",
        help="body shape, e.g. height=1.8 hip=1.1 (core.body.shape.BodyShape fields)",
    )  # fmt: skip
    p.add_argument("--fabric", default="cotton", help="fabric preset: silk, cotton, denim")
    p.add_argument(
        "--solver",
        default=None,
        help="style3d (default), vbd, or implicit (Newton's method, a single surface)",
    )
    p.add_argument(
        "--quality", default="final", help="final (16x32, default: a twirl flares), medium (8x16) "
        "or draft (2x8) substeps x iterations; --substeps/--iterations override",
    )  # fmt: skip
    p.add_argument("--substeps", type=int, default=None, help="solver steps per 1/30 s")
    p.add_argument("--iterations", type=int, default=None, help="solver iterations per step")
    p.add_argument(
        "--chebyshev", type=float, default=None, metavar="RHO",
        help="Chebyshev weight of the solver's iterations, 0 <= RHO < 1; 0 runs them plain "
        "(default: 0.99 for one surface, 0 with cloth-cloth contact)",
    )  # fmt: skip
    p.add_argument(
        "--self-collision", action=argparse.BooleanOptionalAction, default=None,
        help="cloth-cloth contact (default: on for garments in several pieces, e.g. layers)",
    )  # fmt: skip
    p.add_argument("--transition", type=float, default=None, help="rest-to-frame-0 blend, s")
    p.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
        help="another simulation setting (core.sim.config.SimConfig), e.g. --set "
        "implicit_norm=rms --set implicit_tol=0.001",
    )  # fmt: skip
    p.add_argument("--device", default="cpu", help="warp device: cpu or cuda")
    p.add_argument(
        "--preview", nargs="?", const="", default=None, metavar="PNG",
        help="write a contact sheet (default: CACHE.preview.png)",
    )  # fmt: skip
    p.add_argument(
        "--export", nargs="*", default=[], metavar="FILE",
        help="also write the cache as .pc2, .mdd, .npz, USD (.usd, .usda, .usdc) or an OBJ-sequence folder",
    )  # fmt: skip
    p.add_argument(
        "--body-check", action="store_true",
        help="also measure penetration into the skinned body mesh (not only the colliders)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(handler=run)


#: SimConfig fields ``dng simulate`` sets by flags of their own, not by ``--set``.
_FLAGGED = (
    "fabric", "solver", "substeps", "iterations", "chebyshev_rho", "self_collision",
    "transition_s", "device",
)  # fmt: skip


def sim_settings(items: list[str], exclude=(), what: str = "dng simulate's --set may change"):
    """``--set KEY=VALUE`` items -> :class:`~core.sim.config.SimConfig` changes, every key
    checked against its fields (``exclude``: fields set another way)."""
    known = {f.name for f in fields(SimConfig)} - set(exclude)
    changes = dict(parse_setting(item) for item in items)
    for key in changes:
        if key not in known:
            raise InputError(
                f"--set {key}: not a simulation setting {what}; choose from "
                f"{', '.join(sorted(known))}"
            )
    return changes


def _garment(spec: str, shape):

    if Path(spec).suffix.lower() in MESH_SUFFIXES or Path(spec).exists():
        mesh, _ = load_mesh(spec)
        return mesh, spec

    return make_garment(spec, shape=shape), None


def _motion(args, shape):

    spec = args.motion
    if spec is None:
        raise InputError("give --motion (BVH file or procedural kind) or --import CACHE")
    from core.motion.load import MOTION_FILE_SUFFIXES, load_motion

    if Path(spec).suffix.lower() in MOTION_FILE_SUFFIXES or Path(spec).exists():
        source = load_motion(spec, fps=args.fps)
        if tuple(source.skeleton.names) == MANNEQUIN_JOINTS:
            return source
        return retarget(canonical_positions(source), source.fps, shape, name=source.name)

    return make_motion(spec, args.frames, args.fps or 30.0, args.seed, shape)


def _report_path(out: Path, what: str) -> Path:
    return out.with_name(out.stem + what)


def run(args: argparse.Namespace) -> int:

    out = Path(args.out)
    if out.suffix.lower() != ".npz":
        raise InputError("the cache is written as .npz; use --export for other formats", out)
    shape = BodyShape.parse(args.shape)
    garment, gpath = _garment(args.garment, shape)
    if args.import_from:
        cache = import_cache(args.import_from, faces=garment.faces, fps=args.fps)
        if cache.num_vertices != garment.num_vertices:
            raise InputError(
                f"topology mismatch: cache has {cache.num_vertices} vertices, garment "
                f"{args.garment} has {garment.num_vertices}",
                args.import_from,
            )
        save_cache(out, cache)
        for extra in args.export:
            export_cache(extra, cache)
        report = {
            "imported": str(args.import_from), "frames": cache.num_frames,
            "vertices": cache.num_vertices, "fps": cache.fps, "cache": str(out),
        }  # fmt: skip
        print(json.dumps(report, indent=2) if args.json else f"imported {report}")
        return 0

    if args.no_contact and not (args.embed_in and args.motion):
        raise InputError("--no-contact goes with --embed-in and --motion (the body to measure)")
    if args.layers and args.embed_in:
        raise InputError("--layers simulates a proxy; --embed-in drives a garment by one: not both")
    if args.embed_in:
        return _embed(args, garment, out, shape)

    if args.quality not in QUALITY:
        raise InputError(f"unknown --quality {args.quality!r}; choose one of {', '.join(QUALITY)}")
    substeps, iterations = QUALITY[args.quality]
    args.substeps = substeps if args.substeps is None else args.substeps
    args.iterations = iterations if args.iterations is None else args.iterations
    changes = {
        k: v
        for k, v in {
            "solver": args.solver, "substeps": args.substeps, "iterations": args.iterations,
            "transition_s": args.transition, "chebyshev_rho": args.chebyshev,
        }.items()
        if v is not None
    }  # fmt: skip
    config = SimConfig(
        fabric=args.fabric, self_collision=args.self_collision, device=args.device, **changes,
        **sim_settings(args.overrides, _FLAGGED),
    )  # fmt: skip
    motion = _motion(args, shape)
    from core.sim.simulate import simulate

    def progress(done: int, total: int) -> None:
        if not args.json and (done == total or done % 10 == 0):
            print(f"\rframe {done}/{total}", end="" if done < total else "\n", file=sys.stderr)

    # Keep stdout for the JSON report: warp/newton print kernel-build notes.
    # A file's UV seams are split vertices: weld them so the cloth is one piece, and map the
    # result back so the cache has the file's vertices in the file's order.
    welded, index = weld_mesh(garment)
    thickness = None
    if args.layers:
        target, tpath = _garment(args.layers, shape)
        thickness = layer_thickness(welded.vertices, welded.faces, target.vertices, tpath)
    with contextlib.redirect_stdout(sys.stderr if args.json else sys.stdout):
        cache, report = simulate(
            welded, motion, shape, config, path=gpath, progress=progress, thickness=thickness
        )
    if welded.num_vertices != garment.num_vertices:
        cache = unweld_cache(cache, index, garment.faces)
    save_cache(out, cache)
    for extra in args.export:
        export_cache(extra, cache)
    data = report.as_dict()
    data.update(
        cache=str(out), garment=args.garment, motion=motion.name, fabric=config.fabric,
        fps=motion.fps, body_shape=shape.as_dict(), vertices=cache.num_vertices,
        welded_vertices=welded.num_vertices,
    )  # fmt: skip
    if args.body_check:
        data["body_mesh_penetration"] = _body_check(cache, motion, shape)
    if args.preview is not None:
        png = Path(args.preview) if args.preview else _report_path(out, ".preview.png")
        title = f"{args.garment} / {motion.name} / {config.fabric}"
        data["preview"] = str(png)
        data["preview_frames"] = preview_sheet(png, cache, motion, shape, title=title)
    return _write_report(
        args,
        out,
        data,
        f"{out}: {report.frames} frames x {cache.num_vertices} vertices "
        f"({welded.num_vertices} welded), "
        f"{report.ms_per_frame:.0f} ms/frame on {report.device}, "
        f"strain max {report.strain_max:.3f} (limit {report.strain_limit}), "
        f"penetration mean {report.penetration_mean_mm:.3f} mm, "
        f"retried frames {list(report.retried_frames)}, "
        f"refined frames {list(report.refined_frames)}",
    )


def _write_report(args: argparse.Namespace, out: Path, data: dict, summary: str) -> int:
    """Write ``data`` beside the cache ``out`` (``.report.json``), then print it as JSON
    (``--json``) or the one-line ``summary``; the command's exit code."""
    write_json(_report_path(out, ".report.json"), data)
    print(json.dumps(data, indent=2) if args.json else summary)
    return 0


def _embed(args: argparse.Namespace, garment, out: Path, shape: BodyShape) -> int:
    """The garment embedded in a simulated proxy: its cache, and its strain as a report; with
    ``--motion``, kept out of the body's capsules, with its penetration reported."""

    from core.sim.embed import BodyContact, drive, embed, strain_stats

    proxy_file, cache_file = args.embed_in
    proxy, _ = load_mesh(proxy_file)
    cache = load_cache(cache_file)
    welded, index = weld_mesh(proxy)
    if cache.num_vertices not in (proxy.num_vertices, welded.num_vertices):
        raise InputError(
            f"topology mismatch: cache has {cache.num_vertices} vertices, proxy {proxy_file} "
            f"has {proxy.num_vertices} ({welded.num_vertices} welded)",
            cache_file,
        )
    positions = cache.positions
    if cache.num_vertices == proxy.num_vertices:  # a cache of the split file: weld it too
        positions = positions[:, np.unique(index, return_index=True)[1]]
    contact = None
    if args.motion is not None:
        motion = _motion(args, shape)
        if motion.num_frames != cache.num_frames:
            raise InputError(
                f"--motion has {motion.num_frames} frames, the proxy's cache {cache.num_frames}: "
                "give the motion the proxy was simulated under",
                cache_file,
            )
        top = float(welded.vertices[:, 1].max())
        contact = BodyContact(*simulation_colliders(shape, motion, top))
    e = embed(garment.vertices, welded.vertices, welded.faces, target_faces=garment.faces)
    moved = drive(e, positions, None if args.no_contact else contact)
    params = {**cache.params, "target_mode": "embed", "proxy_cache": str(cache_file)}
    save_cache(out, SimCache(moved, garment.faces, cache.fps, params))
    stats = strain_stats(moved, garment.vertices, garment.faces)
    body = {"contact": None}
    summary = ""
    if contact is not None:
        depth = penetration_depths(moved, contact.capsule_ends, contact.radii)
        body = {
            "contact": None if args.no_contact else asdict(contact.settings),
            "penetration_mean_mm": float(depth.mean() * 1e3),
            "penetration_max_mm": float(depth.max() * 1e3),
            "penetrating_fraction": float((depth > 0).mean()),
        }
        kept = "not kept out of the body" if args.no_contact else "kept out of the body"
        summary = f", {kept} (penetration max {body['penetration_max_mm']:.1f} mm)"
    data = {
        "cache": str(out), "garment": args.garment, "proxy": str(proxy_file),
        "proxy_cache": str(cache_file), "frames": len(moved), "vertices": garment.num_vertices,
        **stats.as_dict(), **body,
    }  # fmt: skip
    return _write_report(
        args,
        out,
        data,
        f"{out}: {len(moved)} frames x {garment.num_vertices} vertices embedded in "
        f"{proxy_file}, stretch max {stats.stretch_max:.3f} p99 {stats.stretch_p99:.3f}, "
        f"compression max {stats.compression_max:.3f} p99 {stats.compression_p99:.3f}, "
        f"torn edges {stats.torn_edges}{summary}",
    )


def _body_check(cache, motion, shape) -> dict:
    """Penetration of the free garment vertices into the skinned mannequin mesh, in mm."""

    from core.sim.simulate import mesh_penetration_depths

    body = make_body(shape)
    posed = pose_body(body, motion)
    pinned = cache.params.get("pinned_indices")
    depth = mesh_penetration_depths(cache.positions, posed, body.faces)
    if pinned:
        depth = np.delete(depth, pinned, axis=1)
    return {
        "mean_mm": float(depth.mean() * 1000),
        "p99_mm": float(np.percentile(depth, 99) * 1000),
        "max_mm": float(depth.max() * 1000),
        "penetrating_fraction": float((depth > 0).mean()),
        "body_vertices": int(body.num_vertices),
    }
