"""``dng bench sim``: cloth simulation speed against accuracy, for several solver settings.

For each garment (a ~2k proxy, the built-in ``long-skirt``, and the same skirt refined to
about 10k and 30k vertices) and each (substeps, iterations) setting, the bench simulates the
same clip and reports wall ms per frame and the error against a high-substep reference run of
that garment: mean and max vertex distance over all frames. Writes ``sim.json`` and ``sim.png``
(error against ms/frame) under ``--out``. Timings are wall-clock on the machine it runs on
(CPU unless ``--device cuda``); they include nothing but the solver steps and checks.
"""

from __future__ import annotations

import argparse
import json
import sys

HELP = "cloth simulation: ms/frame and error against a high-substep reference"

#: (substeps per 1/30 s, iterations) settings measured by default, cheapest first.
DEFAULT_SETTINGS = ((1, 4), (2, 4), (2, 8), (4, 8))
#: The reference setting.
DEFAULT_REFERENCE = (8, 16)
#: Garment sizes: the proxy and the refined targets (approximate vertex counts).
DEFAULT_SIZES = (0, 10000, 30000)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from app.bench import add_output_arguments

    add_output_arguments(parser)
    parser.add_argument("--garment", default="long-skirt", help="built-in garment (long-skirt)")
    parser.add_argument(
        "--sizes", default=",".join(map(str, DEFAULT_SIZES)), metavar="N,N,...",
        help="vertex counts: 0 is the garment as built, others refine it (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--settings", default=";".join(f"{s},{i}" for s, i in DEFAULT_SETTINGS),
        metavar="S,I;S,I", help="substeps,iterations pairs (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--reference", default=",".join(map(str, DEFAULT_REFERENCE)), metavar="S,I",
        help="reference substeps,iterations (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument("--motion", default="dance", help="procedural motion kind (dance)")
    parser.add_argument("--frames", type=int, default=20, help="clip frames (20)")
    parser.add_argument("--solver", default="style3d", help="style3d or vbd")
    parser.add_argument("--transition", type=float, default=0.5, help="lead-in blend, s (0.5)")
    parser.add_argument("--settle", type=float, default=0.2, help="lead-in hold, s (0.2)")
    parser.add_argument("--device", default="cpu", help="warp device (cpu or cuda)")


def _pairs(text: str) -> list[tuple[int, int]]:
    from core.errors import InputError

    try:
        out = [tuple(int(x) for x in item.split(",")) for item in text.split(";") if item]
    except ValueError:
        raise InputError(f"bad settings {text!r}: use S,I;S,I") from None
    if not out or any(len(p) != 2 for p in out):
        raise InputError(f"bad settings {text!r}: use S,I;S,I")
    return out


def refine(mesh, target: int):
    """``mesh`` midpoint-subdivided until it has about ``target`` vertices (closest found)."""
    import numpy as np
    import trimesh

    from core.mesh import Mesh

    if target <= mesh.num_vertices:
        return mesh
    e = mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    edge = float(np.median(np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1)))
    best = None
    for f in np.linspace(0.3, 1.0, 15):
        max_edge = edge * f * np.sqrt(mesh.num_vertices / target) * 1.5
        v, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge)
        if best is None or abs(len(v) - target) < abs(len(best[0]) - target):
            best = (v, faces)
    # subdivide_to_size leaves duplicate vertices on shared edges: merge them.
    tm = trimesh.Trimesh(best[0], best[1], process=True)
    return Mesh(np.asarray(tm.vertices, np.float32), np.asarray(tm.faces, np.int64))


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import numpy as np

    from core.body.shape import BodyShape
    from core.fileio import write_json
    from core.motion.procedural import make_motion
    from core.sim.config import SimConfig
    from core.sim.simulate import simulate
    from templates.garments import make_garment

    settings = _pairs(args.settings)
    reference = _pairs(args.reference)[0]
    sizes = [int(s) for s in args.sizes.split(",") if s]
    shape = BodyShape()
    motion = make_motion(args.motion, args.frames, 30.0, 0, shape)
    base = make_garment(args.garment, shape=shape)
    rows = []
    out = Path(args.out)
    for size in sizes:
        garment = refine(base, size)
        runs = {}
        for s, i in [reference, *settings]:
            if (s, i) in runs:
                continue
            cfg = SimConfig(
                substeps=s, iterations=i, solver=args.solver, device=args.device,
                transition_s=args.transition, settle_s=args.settle,
            )  # fmt: skip
            with _quiet():
                cache, report = simulate(garment, motion, shape, cfg)
            runs[(s, i)] = (cache.positions, report)
            print(
                f"{garment.num_vertices:6d} verts  substeps {s:2d} iters {i:2d}: "
                f"{report.ms_per_frame:9.1f} ms/frame",
                file=sys.stderr,
            )
        ref_pos = runs[reference][0]
        for (s, i), (pos, report) in runs.items():
            dist = np.linalg.norm(pos.astype(np.float64) - ref_pos, axis=-1)
            rows.append(
                {
                    "garment": args.garment,
                    "vertices": garment.num_vertices,
                    "substeps": s,
                    "iterations": i,
                    "reference": (s, i) == reference,
                    "ms_per_frame": report.ms_per_frame,
                    "error_mean_mm": float(dist.mean() * 1000),
                    "error_max_mm": float(dist.max() * 1000),
                    "strain_max": report.strain_max,
                    "penetration_mean_mm": report.penetration_mean_mm,
                    "retried_frames": list(report.retried_frames),
                    "device": report.device,
                }
            )
    result = {
        "bench": "sim",
        "motion": args.motion,
        "frames": args.frames,
        "solver": args.solver,
        "reference": list(reference),
        "lead_in_s": [args.transition, args.settle],
        "rows": rows,
    }
    write_json(out / "sim.json", result)
    _plot(out / "sim.png", rows)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for r in rows:
            print(
                f"{r['vertices']:6d} verts  {r['substeps']:2d}x{r['iterations']:<2d} "
                f"{r['ms_per_frame']:9.1f} ms/frame  error mean {r['error_mean_mm']:7.2f} mm  "
                f"max {r['error_max_mm']:7.2f} mm" + ("  (reference)" if r["reference"] else "")
            )
    return 0


def _quiet():
    import contextlib

    return contextlib.redirect_stdout(sys.stderr)


def _plot(path, rows) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from core.fileio import atomic_path

    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    for v in sorted({r["vertices"] for r in rows}):
        pts = sorted(
            (r["ms_per_frame"], r["error_mean_mm"], f"{r['substeps']}x{r['iterations']}")
            for r in rows
            if r["vertices"] == v and not r["reference"]
        )
        if not pts:
            continue
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=f"{v} vertices")
        for x, y, label in pts:
            ax.annotate(label, (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("ms per frame")
    ax.set_ylabel("mean vertex error vs reference (mm)")
    ax.set_title("cloth simulation: speed vs accuracy")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp)
    plt.close(fig)
