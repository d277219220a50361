"""``dng bench proxy``: time and Hausdorff error of proxy derivation against the vertex budget.

Garments: the built-in detailed garments (``templates.garments``) when installed, the synthetic
garments of :mod:`core.proxy.testing` otherwise, and always a 50k-vertex pleated skirt
(``stress-50k``) for the speed target (50k -> 2k with its atlas in under 5 s).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from app.bench import add_output_arguments
from core.errors import InputError
from core.fileio import atomic_path, write_json
from core.mesh import validate_mesh
from core.proxy import ProxyConfig, derive_proxy, testing

HELP = "proxy derivation: time and Hausdorff error for several vertex budgets"

#: Vertex budgets measured by default.
DEFAULT_TARGETS = (250, 500, 1000, 2000, 4000, 8000)
#: Built-in detailed garments (``templates.garments.make_garment`` names).
BUILTIN_GARMENTS = ("multilayer-skirt", "double-skirt", "tango-skirt", "pleated-skirt", "dress")


def add_arguments(parser: argparse.ArgumentParser) -> None:

    add_output_arguments(parser)
    parser.add_argument(
        "--targets", default=",".join(map(str, DEFAULT_TARGETS)), metavar="N,N,...",
        help="vertex budgets (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--garments", default="", metavar="NAME,...",
        help="garments to run (default: all built-in ones, or the synthetic set, plus stress-50k)",
    )  # fmt: skip
    parser.add_argument(
        "--synthetic",
        action="store_true",
        help="use the synthetic garments even if built-ins exist",
    )


def garments(names: list[str], synthetic: bool) -> dict:
    """Name -> Mesh for the bench; ``stress-50k`` is always available."""
    makers = {
        "stress-50k": lambda: testing.skirt_tube(
            folds=30, fold_depth=0.015, n_around=400, n_along=126
        ),
        "synthetic-layered-skirt": testing.layered_skirt,
        "synthetic-pleated-skirt": lambda: testing.skirt_tube(
            folds=24, fold_depth=0.02, n_around=256, n_along=100
        ),
        "synthetic-tshirt": testing.tshirt,
    }
    builtin = None
    if not synthetic:
        try:
            from templates.garments import make_garment

            builtin = make_garment
        except ImportError:
            builtin = None
    if not names:
        names = list(BUILTIN_GARMENTS) if builtin else [n for n in makers if n != "stress-50k"]
        names.append("stress-50k")
    out = {}
    for name in names:
        if name in makers:
            out[name] = validate_mesh(*makers[name]())[0]
        elif builtin is not None:
            try:
                out[name] = builtin(name)
            except (KeyError, ValueError) as exc:
                raise InputError(f"unknown garment {name!r}: {exc}") from None
        else:
            raise InputError(f"unknown garment {name!r} (built-in garments are not installed)")
    return out


def run(args: argparse.Namespace) -> int:

    try:
        targets = [int(t) for t in args.targets.split(",") if t.strip()]
    except ValueError:
        raise InputError(
            f"--targets must be integers separated by commas, got {args.targets!r}"
        ) from None
    names = [n.strip() for n in args.garments.split(",") if n.strip()]
    meshes = garments(names, args.synthetic)
    rows = []
    for name, mesh in meshes.items():
        for target in targets:
            start = time.perf_counter()
            result = derive_proxy(mesh, ProxyConfig(target_verts=target))
            wall = time.perf_counter() - start
            r = result.report
            steps = r["timings_s"]
            rows.append(
                {
                    "garment": name,
                    "input_vertices": mesh.num_vertices,
                    "target_verts": target,
                    "vertices": r["proxy"]["vertices"],
                    "faces": r["proxy"]["faces"],
                    "count_error": r["proxy"]["vertices"] / target - 1,
                    "components": r["proxy"]["components"],
                    "boundary_loops": r["proxy"]["boundary_loops"],
                    "layers": r["layers"]["used"],
                    "hausdorff_m": r["distance"]["hausdorff_m"],
                    "hausdorff_rel": r["distance"]["hausdorff_rel"],
                    "target_to_proxy_rel": r["distance"]["target_to_proxy_m"]
                    / r["target"]["bbox_diagonal_m"],
                    "proxy_to_target_rel": r["distance"]["proxy_to_target_m"]
                    / r["target"]["bbox_diagonal_m"],
                    "uv_charts": r["uv"]["charts"],
                    "uv_flipped": r["uv"]["flipped"],
                    "uv_in_unit_square": r["uv"]["in_unit_square"],
                    "utilization": r["uv"]["utilization"],
                    "stretch_max": r["uv"]["stretch_max"],
                    "slivers": r["proxy"]["slivers"],
                    "proxy_s": round(sum(v for k, v in steps.items() if k != "measure"), 4),
                    "measure_s": steps["measure"],
                    "wall_s": round(wall, 4),
                    "steps_s": steps,
                }
            )
            if not args.json:
                row = rows[-1]
                print(
                    f"{name:26s} {target:6d} -> {row['vertices']:6d} v  "
                    f"H {row['hausdorff_rel']:.2%}  proxy {row['proxy_s']:.2f} s  "
                    f"(+ measure {row['measure_s']:.2f} s)  {row['layers']}"
                )
    out = Path(args.out)
    table = {"bench": "proxy", "targets": targets, "rows": rows}
    write_json(out / "proxy.json", table)
    plot(rows, out / "proxy.png")
    if args.json:
        print(json.dumps(table, indent=2))
    else:
        print(f"wrote {out / 'proxy.json'} and {out / 'proxy.png'}")
    return 0


def plot(rows: list[dict], path) -> None:
    """Hausdorff error and time against the vertex budget, one line per garment (matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    ticks = sorted({r["target_verts"] for r in rows})
    fig, (ax_err, ax_time) = plt.subplots(1, 2, figsize=(11, 4.2))
    for name in dict.fromkeys(r["garment"] for r in rows):
        sel = [r for r in rows if r["garment"] == name]
        x = [r["vertices"] for r in sel]
        ax_err.plot(x, [100 * r["hausdorff_rel"] for r in sel], "o-", label=name)
        ax_time.plot(x, [r["proxy_s"] for r in sel], "o-", label=name)
    ax_err.axhline(3.0, color="gray", ls="--", lw=0.8)
    for ax, label in (
        (ax_err, "Hausdorff / bbox diagonal (%)"),
        (ax_time, "proxy + atlas time (s)"),
    ):
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xticks(ticks, [str(t) for t in ticks])
        ax.set_xlabel("proxy vertices")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    ax_time.axhline(5.0, color="gray", ls="--", lw=0.8)
    ax_err.legend(fontsize=7)
    fig.suptitle("Coarse proxy: error and time vs vertex budget")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
