"""``dng bench sim``: how far each simulation quality is from convergence, and what it costs.

For each clip (``dance``, ``walk``, ``jump``, ``twirl`` and CMU 01_01 retargeted, when the file
is on this machine) and each quality (substeps x iterations), the bench simulates the garment
(default: the ``long-skirt`` template at 50 mm, 1000 vertices, a proxy's size) and a
reference run twice as fine in time and in iterations (2x the substeps, the solver iterations
and the linear solver's iterations; for ``--set solver=implicit``, half the Newton tolerance
``implicit_tol``), and reports
the vertex distance between the two (mean and 95th percentile over vertices and frames, mm; and
the mean at frame 0, where the lead-in's drape already differs), the hem's mean radius about the
waist's axis and its mean height against the reference's (:func:`hem_stats_distance`), wall ms
per clip frame, the largest and 99th-percentile edge strain, and, with ``--floor``, whether the
quality is **converged** (:func:`converged`: no farther from its 2x run than from its floor, the
same run on the garment moved 10 um, and its strain within the sanity limit). Writes
``sim.json`` and ``sim.png`` (distance against ms/frame, one line per clip) under ``--out``.

Clips are short by default (30 frames after a 0.7 s lead-in) so the bench takes minutes on
2 cores; ``--frames`` and ``--clips`` measure more. Timings are wall-clock on this machine and
count only the clip's solver steps and checks.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from app.bench import add_output_arguments
from app.commands.simulate import sim_settings
from core.body.shape import BodyShape
from core.errors import InputError
from core.fileio import atomic_path, write_json
from core.mesh import load_mesh
from core.motion.procedural import PROCEDURAL_KINDS, make_motion
from core.sim.config import QUALITY, SimConfig
from core.sim.sanity import FLOOR_PERTURBATION_M, hem_indices, hem_radius, perturbed
from core.sim.thickness import layer_thickness
from pipeline.config import CMU_CLIP, MotionSpec, PipelineConfig
from pipeline.stages.motions import motion_from_spec
from templates.garments import make_garment

HELP = "cloth simulation: each quality's distance to a run twice as fine, ms/frame, strain"

#: Clips measured by default; ``cmu-01_01`` is CMU 01_01 retargeted (skipped when absent).
DEFAULT_CLIPS = ("dance", "walk", "jump", "twirl", "cmu-01_01")


def add_arguments(parser: argparse.ArgumentParser) -> None:

    add_output_arguments(parser)
    parser.add_argument(
        "--garment", default="long-skirt", help="built-in garment or mesh file (long-skirt)"
    )
    parser.add_argument(
        "--resolution", type=float, default=50.0,
        help="built-in garment's edge length, mm (50: 1000 vertices for long-skirt)",
    )  # fmt: skip
    parser.add_argument(
        "--clips", default=",".join(DEFAULT_CLIPS), metavar="A,B,...",
        help="procedural kinds and/or cmu-01_01 (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--qualities", default=",".join(QUALITY), metavar="Q,Q,...",
        help="quality names (core.sim.config.QUALITY; default: %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--settings", default="", metavar="S,I;S,I",
        help="extra substeps,iterations pairs to measure beside the named qualities",
    )  # fmt: skip
    parser.add_argument(
        "--linear", type=int, default=None,
        help="linear solver iterations of every setting (default: SimConfig's)",
    )  # fmt: skip
    parser.add_argument("--frames", type=int, default=30, help="clip frames (30)")
    parser.add_argument("--seed", type=int, default=0, help="procedural motion seed (0)")
    parser.add_argument("--fabric", default="cotton", help="fabric preset (cotton)")
    parser.add_argument("--transition", type=float, default=0.5, help="lead-in blend, s (0.5)")
    parser.add_argument("--settle", type=float, default=0.2, help="lead-in hold, s (0.2)")
    parser.add_argument("--device", default="cpu", help="warp device (cpu or cuda)")
    parser.add_argument(
        "--floor",
        action="store_true",
        help="also run each setting on the garment moved by 10 um at random: how far the "
        "cloth's own sensitivity alone moves it (the distance no finer setting can remove)",
    )
    parser.add_argument(
        "--layers", metavar="TARGET",
        help="the garment is a proxy: keep it off the body by the depth of TARGET's layers "
        "beneath it, as dng demo simulates a project's proxy (and dng simulate --layers)",
    )  # fmt: skip
    parser.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
        help="another simulation setting of every run (core.sim.config.SimConfig), e.g. "
        "--set chebyshev_rho=0",
    )  # fmt: skip


#: SimConfig fields each measured setting (and its reference) decides itself.
_MEASURED_FIELDS = ("substeps", "iterations", "linear_iterations")


def sim_overrides(items: list[str]) -> dict:
    """``--set KEY=VALUE`` items -> SimConfig changes, every key checked against its fields
    (those each measured setting decides are not the bench's to set)."""
    return sim_settings(items, _MEASURED_FIELDS, "the bench may change")


def _pairs(text: str) -> list[tuple[int, int]]:

    try:
        out = [tuple(int(x) for x in item.split(",")) for item in text.split(";") if item]
    except ValueError:
        raise InputError(f"bad settings {text!r}: use S,I;S,I") from None
    if any(len(p) != 2 or min(p) < 1 for p in out):
        raise InputError(f"bad settings {text!r}: use S,I;S,I with positive integers")
    return out


def settings_to_measure(qualities: str, extra: str) -> list[tuple[str, tuple[int, int]]]:
    """(label, (substeps, iterations)) for the named qualities, then the extra pairs."""
    out = []
    for name in [q for q in qualities.split(",") if q]:
        if name not in QUALITY:
            raise InputError(f"unknown quality {name!r}; choose from {', '.join(QUALITY)}")
        out.append((name, QUALITY[name]))
    out += [(f"{s}x{i}", (s, i)) for s, i in _pairs(extra)]
    if not out:
        raise InputError("nothing to measure: give --qualities or --settings")
    return out


def bench_motion(clip: str, frames: int, seed: int, shape):
    """The clip's motion on the mannequin of ``shape``, or None for a CMU file not here."""
    if clip in PROCEDURAL_KINDS:
        return make_motion(clip, frames, 30.0, seed, shape)
    if clip == "cmu-01_01":
        if not CMU_CLIP.is_file():
            return None
        spec = MotionSpec(clip, "file", frames, path=str(CMU_CLIP), start_s=2.0)
        return motion_from_spec(spec, PipelineConfig(body=shape))
    raise InputError(f"unknown clip {clip!r}; use {', '.join(PROCEDURAL_KINDS)} or cmu-01_01")


def distance_stats(positions, reference) -> tuple[float, float]:
    """Mean and 95th percentile (mm) of the vertex distances between two (T, V, 3) runs."""
    d = np.linalg.norm(np.asarray(positions, np.float64) - reference, axis=-1)
    return float(d.mean() * 1000), float(np.percentile(d, 95) * 1000)


def hem_stats_distance(positions, reference, hem, waist) -> tuple[float, float]:
    """How far a run's hem is from the reference's as a whole, frame by frame: the mean over
    frames of the absolute difference of the hem's mean radius about the waist's axis and of
    its mean height (mm). Unlike vertex distances they do not see a fold turned about the
    axis; they do see how far the folds stand out, and on the quick proxy two converged runs
    (``--set solver=implicit --floor``) still differ by 7-33 mm in them (docs/decisions.md,
    "What counts as converged"): a measure to read beside the vertex distances, not a convergence target.

    Parameters
    ----------
    positions, reference : (T, V, 3) float
    hem : (L,) int hem loop, waist : (P,) int pinned waistband vertices
    """
    a, b = np.asarray(positions, np.float64), np.asarray(reference, np.float64)
    radius = np.abs(hem_radius(a, hem, waist) - hem_radius(b, hem, waist)).mean()
    height = np.abs(a[:, hem, 1].mean(1) - b[:, hem, 1].mean(1)).mean()
    return float(radius * 1000), float(height * 1000)


def converged(row: dict) -> bool | None:
    """The floor rule (docs/decisions.md, "What counts as converged"): a setting is converged
    when its mean distance to its 2x run is no larger than its floor's (the same setting on the
    garment moved 10 um: whatever error it has hides in the cloth's own sensitivity) and its
    largest edge strain is within the sanity limit. None without a floor (``--floor``)."""
    if "floor_mean_mm" not in row:
        return None
    return bool(row["mean_mm"] <= row["floor_mean_mm"] and row["strain_max"] <= row["strain_limit"])


def bench_garment(spec: str, resolution: float, shape):
    """The garment a simulation bench runs: a mesh file, or a built-in garment made at
    ``resolution`` mm on ``shape``'s mannequin."""
    if Path(spec).exists():
        return load_mesh(spec)[0]
    return make_garment(spec, resolution, shape=shape)


def run(args: argparse.Namespace) -> int:

    from core.sim.simulate import simulate

    if args.frames < 2:
        raise InputError(f"--frames must be at least 2, got {args.frames}")
    measured = settings_to_measure(args.qualities, args.settings)
    clips = [c for c in args.clips.split(",") if c]
    lin = SimConfig().linear_iterations if args.linear is None else args.linear
    if lin < 1:
        raise InputError(f"--linear must be at least 1, got {lin}")
    base = replace(
        SimConfig(
            fabric=args.fabric, device=args.device, transition_s=args.transition,
            settle_s=args.settle,
        ),
        **sim_overrides(args.overrides),
    )  # fmt: skip
    shape = BodyShape()
    garment = bench_garment(args.garment, args.resolution, shape)
    hem = hem_indices(garment.vertices, garment.faces)
    thickness = None
    if args.layers:
        target = load_mesh(args.layers)[0]
        thickness = layer_thickness(garment.vertices, garment.faces, target.vertices, args.layers)
    rows, skipped = [], []
    for clip in clips:
        motion = bench_motion(clip, args.frames, args.seed, shape)
        if motion is None:
            skipped.append(clip)
            print(f"{clip}: clip file not on this machine, skipped", file=sys.stderr)
            continue
        runs: dict = {}

        def sim(s: int, i: int, lin: int, tol: float, moved=False, clip=clip, motion=motion,
                runs=runs):  # fmt: skip
            """One run at s x i (linear ``lin``; the implicit solver's tolerance ``tol``)."""
            if (s, i, lin, tol, moved) not in runs:
                cfg = replace(
                    base, substeps=s, iterations=i, linear_iterations=lin, implicit_tol=tol
                )
                mesh = perturbed(garment, FLOOR_PERTURBATION_M, args.seed) if moved else garment
                with _quiet():
                    cache, report = simulate(mesh, motion, shape, cfg, thickness=thickness)
                runs[(s, i, lin, tol, moved)] = (cache.positions, report, cache.params)
                print(
                    f"{clip:10s} {s:2d}x{i:<2d} linear {lin:3d} {report.ms_per_frame:8.1f} ms/frame"
                    + (" (moved 10 um)" if moved else ""),
                    file=sys.stderr, flush=True,
                )  # fmt: skip
            return runs[(s, i, lin, tol, moved)]

        for label, (s, i) in measured:
            tol = base.implicit_tol
            pos, report, params = sim(s, i, lin, tol)
            ref_pos, ref_report, _ = sim(2 * s, 2 * i, 2 * lin, tol / 2)
            mean_mm, p95_mm = distance_stats(pos, ref_pos)
            waist = np.asarray(params["pinned_indices"], np.int64)
            hem_r, hem_y = hem_stats_distance(pos, ref_pos, hem, waist)
            floor = {}
            if args.floor:
                moved = sim(s, i, lin, tol, moved=True)[0]
                f_mean, f_p95 = distance_stats(moved, pos)
                f_r, f_y = hem_stats_distance(moved, pos, hem, waist)
                floor = {
                    "floor_mean_mm": round(f_mean, 2), "floor_p95_mm": round(f_p95, 2),
                    "floor_frame0_mean_mm": round(distance_stats(moved[:1], pos[:1])[0], 2),
                    "floor_hem_radius_mm": round(f_r, 2), "floor_hem_height_mm": round(f_y, 2),
                }  # fmt: skip
            rows.append(
                {
                    "clip": clip,
                    "quality": label,
                    "substeps": s,
                    "iterations": i,
                    "linear_iterations": lin,
                    "reference": [2 * s, 2 * i, 2 * lin],
                    **({"implicit_tol": [tol, tol / 2]} if base.solver == "implicit" else {}),
                    "mean_mm": round(mean_mm, 2),
                    "p95_mm": round(p95_mm, 2),
                    "frame0_mean_mm": round(distance_stats(pos[:1], ref_pos[:1])[0], 2),
                    "hem_radius_mm": round(hem_r, 2),
                    "hem_height_mm": round(hem_y, 2),
                    "ms_per_frame": report.ms_per_frame,
                    "reference_ms_per_frame": ref_report.ms_per_frame,
                    "strain_max": round(report.strain_max, 4),
                    "strain_p99": round(report.strain_p99, 4),
                    "strain_limit": report.strain_limit,
                    "penetration_p99_mm": round(report.penetration_p99_mm, 2),
                    "retried_frames": list(report.retried_frames),
                    "refined_frames": list(report.refined_frames),
                    "device": report.device,
                    **floor,
                }
            )
            rows[-1]["converged"] = converged(rows[-1])
    result = {
        "bench": "sim",
        "garment": args.garment,
        "vertices": garment.num_vertices,
        "frames": args.frames,
        "seed": args.seed,
        "fabric": args.fabric,
        "layers": args.layers,
        "layers_depth_max_mm": None
        if thickness is None
        else round(1e3 * float(thickness.max()), 2),
        "lead_in_s": [args.transition, args.settle],
        "sim": {k: v for k, v in base.as_dict().items() if k not in _MEASURED_FIELDS},
        "skipped_clips": skipped,
        "rows": rows,
    }
    out = Path(args.out)
    write_json(out / "sim.json", result)
    _plot(out / "sim.png", rows, garment.num_vertices)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(format_table(rows, garment.num_vertices, args.frames))
    return 0


def format_table(rows: list[dict], vertices: int, frames: int) -> str:
    """The rows as a Markdown table (what the config's docstring and the README quote)."""
    head = (
        f"{vertices} vertices, {frames} frames; distance to a run with 2x substeps, 2x "
        "iterations and 2x linear iterations\n\n"
        "| clip | quality | S x I x L | mean mm | p95 mm | hem radius / height mm | ms/frame "
        "| strain max | strain p99 | converged |\n"
        "|---|---|---|---:|---:|---:|---:|---:|---:|---|"
    )
    floor = any("floor_mean_mm" in r for r in rows)
    if floor:
        head = head.replace("| ms/frame |", "| floor mean / p95 mm | ms/frame |")
        head = head.replace("|---:|---:|---:|---:|---:|", "|---:|---:|---:|---:|---:|---:|")
        head = head.replace(
            "\n\n",
            "; floor: the same setting on the garment moved 10 um at random (the cloth's own "
            "sensitivity, which no finer setting removes); converged: no farther from the 2x "
            "run than the floor (mean), strain max within the sanity limit\n\n",
            1,
        )
    lines = [head]
    verdict = {True: "yes", False: "no", None: "needs --floor"}
    for r in rows:
        cells = [
            r["clip"], r["quality"], f"{r['substeps']}x{r['iterations']}x{r['linear_iterations']}",
            f"{r['mean_mm']:.1f}", f"{r['p95_mm']:.1f}",
            f"{r['hem_radius_mm']:.1f} / {r['hem_height_mm']:.1f}",
        ]  # fmt: skip
        if floor:
            cells.append(f"{r.get('floor_mean_mm', float('nan')):.1f} / "
                         f"{r.get('floor_p95_mm', float('nan')):.1f}")  # fmt: skip
        cells += [f"{r['ms_per_frame']:.0f}", f"{r['strain_max']:.3f}", f"{r['strain_p99']:.3f}"]
        cells.append(verdict[r.get("converged")])
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _quiet():

    return contextlib.redirect_stdout(sys.stderr)


def _plot(path, rows, vertices: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=100)
    for clip in dict.fromkeys(r["clip"] for r in rows):
        pts = sorted(
            (r["ms_per_frame"], r["mean_mm"], r["p95_mm"], r["quality"])
            for r in rows
            if r["clip"] == clip
        )
        (line,) = ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=f"{clip} mean")
        ax.plot([p[0] for p in pts], [p[2] for p in pts], "^:", color=line.get_color(), alpha=0.6)
        for x, y, _, label in pts:
            ax.annotate(label, (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("ms per frame")
    ax.set_ylabel("distance to 2x finer run (mm; o mean, ^ p95)")
    ax.set_title(f"cloth simulation convergence, {vertices} vertices")
    ax.grid(True, alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp)
    plt.close(fig)
