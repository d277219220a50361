"""Joint2Coarse against an ensemble of simulations: its headline ratio on a project's test
motions and on any other motion (issue: "Joint2Coarse is held against an ensemble").

Usage: ``python benchmarks/joint2coarse_ensemble.py PROJECT [--motion FILE|KIND ...]
[--frames N] [--realisations 2] [--json]``

For each motion (default: the project's test motions, as the project made them; ``--motion``:
motion files or procedural kinds instead, as ``dng eval joint2coarse`` takes them), the proxy
is simulated N + 1 times (the project's settings; N of them with the proxy moved 10 um by
offsets of their own; cached outside the project), and Joint2Coarse's prediction is scored
against each (:func:`pipeline.joint2coarse_eval.evaluate_on_motion`). The **ensemble ratio**
is its mean error over the mean of the others' (each simulation against the mean of the other
N): 1 is as close as the motion's likely outcome comes. Beside it, the millimetres, and the
physics of prediction and simulation: body penetration (share of vertices inside), stretch
(p99 of the edges' strain) and the hem's radius (the prediction's mean difference from the
simulation's, mm).

Prints one row per motion and the mean ratio; ``--json``: ``{"command": ..., "rows": [...],
"mean_ratio": ...}`` for ``dng report PROJECT --results docs/results.md --bench
joint2coarse-ensemble=FILE`` (the command names motion files by their names alone).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from core.errors import InputError
from core.project import Project
from pipeline.config import available_test_motions, project_config
from pipeline.joint2coarse_eval import eval_motion, evaluate_on_motion
from pipeline.stages.motions import load_project_motion


def ensemble_row(report: dict) -> dict:
    """One motion's flat record from :func:`evaluate_on_motion`'s report (with realisations)."""
    r = report["realisations"]
    model = report["model"]
    pen, stretch = report["penetration"], report["stretch"]
    return {
        "motion": report["motion"],
        "frames": report["frames"],
        "simulations": r["simulations"],
        "ours_mm": r["error_mm"][model]["mean_mm"],
        "mean_of_others_mm": r["mean_of_others_mm"]["mean_mm"],
        "between_simulations_mm": r["between_simulations_mm"]["mean_mm"],
        "ensemble_ratio": r["ensemble_ratio"][model],
        "inside_pct_prediction": pen["prediction"]["inside_percent"],
        "inside_pct_simulation": pen["simulation"]["inside_percent"],
        "stretch_p99_prediction": stretch["prediction"]["p99"],
        "stretch_p99_simulation": stretch["simulation"]["p99"],
        "hem_radius_difference_mm": report["hem_radius_mm"]["prediction"]["mean_difference"],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project")
    ap.add_argument("--motion", action="append", default=[], metavar="FILE|KIND")
    ap.add_argument("--frames", type=int, default=None, help="frames of each --motion")
    ap.add_argument("--realisations", type=int, default=2, metavar="N")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    log = (lambda m: print(m, file=sys.stderr, flush=True)) if args.json else print
    try:
        if args.realisations < 2:
            raise InputError(f"--realisations {args.realisations}: the ratio needs at least 2")
        project = Project(args.project)
        config = project_config(project)
        if args.motion:
            motions = [(Path(m).stem, eval_motion(config, m, args.frames)) for m in args.motion]
        else:
            motions = [
                (s.name, load_project_motion(project, s.name))
                for s in available_test_motions(config)
            ]
        rows = []
        for name, motion in motions:
            report = evaluate_on_motion(
                project, config, motion, name, log, realisations=args.realisations
            )
            rows.append({**ensemble_row(report), "motion": name})
            row = rows[-1]
            log(
                f"{name}: {row['ensemble_ratio']:.2f}x (ours {row['ours_mm']:.1f} mm, the mean "
                f"of the others {row['mean_of_others_mm']:.1f}, the simulations apart "
                f"{row['between_simulations_mm']:.1f}; stretch p99 "
                f"{row['stretch_p99_prediction']:.3f} / {row['stretch_p99_simulation']:.3f}, "
                f"inside {row['inside_pct_prediction']:.2f} / "
                f"{row['inside_pct_simulation']:.2f} %, prediction / simulation)"
            )
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    mean = float(np.mean([r["ensemble_ratio"] for r in rows])) if rows else None
    if args.json:
        command = "python benchmarks/joint2coarse_ensemble.py PROJECT" + "".join(
            f" --motion {Path(m).name}" for m in args.motion
        )
        command += f" --frames {args.frames}" if args.frames else ""
        command += f" --realisations {args.realisations}"
        out = {"command": command, "rows": rows, "mean_ratio": mean}
        print(json.dumps({**out, "realisations": args.realisations}))
    elif mean is not None:
        print(f"mean ensemble ratio over {len(rows)} motions: {mean:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
