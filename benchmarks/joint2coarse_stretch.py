"""Joint2Coarse's strain limit: what each limit does to a project's validation predictions
(how :data:`training.joint2coarse.config.PREDICTION_STRETCH` and ``PREDICTION_SWEEPS`` were
chosen; docs/decisions.md, "Joint2Coarse's prediction strain-limited").

Usage: ``python benchmarks/joint2coarse_stretch.py PROJECT [--limits 0.01 0.02 0.05]
[--sweeps 10 30] [--split validation|test] [--json]``

For each motion of the split, the project's Joint2Coarse predicts the proxy as it comes (no
limit), then with every limit and sweep count (:func:`core.strain.limit_stretch` against the
proxy's rest shape). Each row is the mean over the motions of: the vertex error against the
project's simulation (mean mm), the edges' stretch (p99 and max over every edge and frame, as
the report measures it) and the limit's cost (ms a frame, on top of the prediction). The
simulation's own stretch is the last row.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from core.errors import InputError
from core.mesh import load_mesh
from core.project import Project
from core.sim import load_cache
from core.sim.embed import strain_stats
from core.strain import limit_stretch, stretch_limit
from pipeline.stages.motions import load_project_motion


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project")
    ap.add_argument("--limits", type=float, nargs="+", default=[0.01, 0.02, 0.05])
    ap.add_argument("--sweeps", type=int, nargs="+", default=[10, 30])
    ap.add_argument("--split", choices=("validation", "test"), default="validation")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    try:
        rows = measure(Project(args.project), args.split, args.limits, args.sweeps)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        command = (
            f"python benchmarks/joint2coarse_stretch.py PROJECT --split {args.split} --limits "
            + " ".join(map(str, args.limits))
            + " --sweeps "
            + " ".join(map(str, args.sweeps))
        )
        print(json.dumps({"command": command, "rows": rows}))
        return 0
    print(f"mean over the {args.split} motions")
    print("| prediction | error mean (mm) | stretch p99 | stretch max | ms/frame |")
    print("| --- | --- | --- | --- | --- |")
    for r in rows:
        ms = "" if r["ms_per_frame"] is None else f"{r['ms_per_frame']:.2f}"
        error = "" if r["error_mm"] is None else f"{r['error_mm']:.2f}"
        print(f"| {r['name']} | {error} | {r['stretch_p99']:.3f} | {r['stretch_max']:.3f} | {ms} |")
    return 0


def measure(project: Project, split: str, limits, sweeps) -> list[dict]:
    """Rows (name, error_mm, stretch_p99, stretch_max, ms_per_frame), each the mean over the
    split's motions: the prediction as it comes, then each (limit, sweeps), then the simulation."""
    from training.joint2coarse import joint2coarse_inputs, load_model, predict_proxy, vertex_errors

    report_file = project.path("joint2coarse", "report.json")
    model_file = project.path("joint2coarse", "joint2coarse.pt")
    for f in (report_file, model_file):
        if not f.is_file():
            raise InputError("the project has no trained Joint2Coarse: run dng demo first", f)
    splits = json.loads(report_file.read_text())["splits"]
    names = splits["validation" if split == "validation" else "test"]
    if not names:
        raise InputError(f"the project's Joint2Coarse has no {split} motions", report_file)
    net = load_model(model_file)
    proxy = load_mesh(project.path("proxy", "positions.obj"))[0]
    rest, faces = proxy.vertices, proxy.faces
    settings = [(None, None)] + [(lim, n) for lim in limits for n in sweeps]
    out: dict = {s: [] for s in [*settings, "simulation"]}
    for name in names:
        joints, root_rot = joint2coarse_inputs(load_project_motion(project, name))
        reference = load_cache(project.path(f"sim/{name}-proxy", "cache.npz")).positions
        raw = predict_proxy(net, joints, root_rot)
        for lim, n in settings:
            start = time.perf_counter()
            pred = raw if lim is None else limit_stretch(raw, stretch_limit(rest, faces, lim, n))
            ms = None if lim is None else 1e3 * (time.perf_counter() - start) / len(raw)
            st = strain_stats(pred, rest, faces)
            error = vertex_errors(pred.astype(np.float32), reference).mean_mm
            out[lim, n].append((error, st.stretch_p99, st.stretch_max, ms))
        st = strain_stats(reference, rest, faces)
        out["simulation"].append((None, st.stretch_p99, st.stretch_max, None))
    rows = []
    for key, values in out.items():
        name = (
            "simulation"
            if key == "simulation"
            else "as it comes"
            if key[0] is None
            else f"limit {key[0]:g}, {key[1]} sweeps"
        )
        cols = list(zip(*values))

        def mean(c):
            return None if c[0] is None else float(np.mean(c))

        rows.append(
            {
                "name": name,
                "limit": None if key == "simulation" else key[0],
                "sweeps": None if key == "simulation" else key[1],
                "error_mm": mean(cols[0]),
                "stretch_p99": mean(cols[1]),
                "stretch_max": mean(cols[2]),
                "ms_per_frame": mean(cols[3]),
            }
        )
    return rows


if __name__ == "__main__":
    sys.exit(main())
