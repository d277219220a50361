"""How far the cloth solver's iterations are from converged within one clip frame.

Usage: ``python benchmarks/sim_step_convergence.py [--garment G] [--motion walk] [--frame 10]
[--substeps 8] [--iterations 16 64 256] [--rhos 0 0.99] [--reference 2048] [--linear 10]
[--set KEY=VALUE] [--json]``

``dng bench sim`` compares whole runs of two settings; this isolates the part that iterations
decide. It simulates the garment (a mesh file, or a built-in garment at 50 mm; default the
``long-skirt`` template) under the clip at ``--substeps`` x ``--iterations[0]`` (otherwise as
``dng simulate`` runs it: its lead-in, and a proxy's Chebyshev weight) up to clip frame
``--frame``, then runs the
next frame's solver steps again from that one state, once per (rho, iterations), and once plain
with ``--reference`` iterations a step: the step converged, up to what the reference's own
iterations leave. Prints, per setting, the frame's wall ms and the mean and largest vertex
distance (mm) to the reference, beside how far the reference moved the cloth in that frame.

Linear (conjugate-gradient) iterations per solver iteration are ``--linear``; the reference uses
the same, and a run with more (``--linear 40``) shows what they decide.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def measure(
    garment, motion, shape, frame: int, substeps: int, settings, reference: int, linear: int,
    overrides: dict | None = None,
) -> dict:  # fmt: skip
    """One frame's steps from the same state, per (rho, iterations) in ``settings``.

    Returns ``{"moved_mm", "rows": [{"rho", "iterations", "ms", "mean_mm", "max_mm"}, ...]}``:
    distances of each setting's cloth after the frame to the reference's (plain, ``reference``
    iterations a step), and the reference's mean displacement over the frame. ``overrides``:
    other :class:`~core.sim.config.SimConfig` settings of every run.
    """
    from core.errors import InputError
    from core.sim.config import SimConfig
    from core.sim.simulate import prepare
    from core.sim.style3d import chebyshev_omegas

    if not 1 <= frame < motion.num_frames - 1:
        raise InputError(f"--frame must be in 1..{motion.num_frames - 2}, got {frame}")
    if min(k for _, k in settings) < 1 or reference < 1 or linear < 1 or substeps < 1:
        raise InputError("--iterations, --reference, --linear and --substeps must be at least 1")
    if not all(0 <= r < 1 for r, _ in settings):
        raise InputError("--rhos must be in [0, 1)")
    config = SimConfig(
        substeps=substeps, iterations=settings[0][1], linear_iterations=linear,
        **(overrides or {}),
    )  # fmt: skip
    with contextlib.redirect_stdout(sys.stderr):
        run = prepare(garment, motion, shape, config)
    scene, drive = run.scene, run.drive
    run.step(0, drive.frame_step(frame))
    before, start = scene.positions(), scene.snapshot()
    a, b = drive.frame_step(frame), drive.frame_step(frame + 1)

    def one_frame(rho: float, iterations: int) -> tuple[np.ndarray, float]:
        scene.restore(start)
        scene.style3d_step.omegas = chebyshev_omegas(rho, iterations)
        t = time.perf_counter()
        run.step(a, b)
        return scene.positions(), (time.perf_counter() - t) * 1000

    ref, _ = one_frame(0.0, reference)
    rows = []
    for rho, iterations in settings:
        pos, ms = one_frame(rho, iterations)
        d = np.linalg.norm(pos.astype(np.float64) - ref, axis=1) * 1000
        rows.append(
            {"rho": rho, "iterations": iterations, "ms": round(ms, 1),
             "mean_mm": round(float(d.mean()), 3), "max_mm": round(float(d.max()), 2)}
        )  # fmt: skip
    moved = np.linalg.norm(ref.astype(np.float64) - before, axis=1) * 1000
    return {"moved_mm": round(float(moved.mean()), 2), "rows": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--garment", default="long-skirt", help="mesh file or built-in garment")
    parser.add_argument("--motion", default="walk", help="procedural kind or cmu-01_01 (walk)")
    parser.add_argument("--frames", type=int, default=30, help="clip length (30)")
    parser.add_argument("--frame", type=int, default=10, help="the clip frame measured (10)")
    parser.add_argument("--substeps", type=int, default=8)
    parser.add_argument("--iterations", type=int, nargs="+", default=[16, 64, 256])
    parser.add_argument("--rhos", type=float, nargs="+", default=[0.0, 0.99])
    parser.add_argument("--reference", type=int, default=2048, help="reference iterations")
    parser.add_argument("--linear", type=int, default=10, help="CG iterations per iteration")
    parser.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
        help="another simulation setting of every run, e.g. --set contact_ke=1",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print only the JSON")
    args = parser.parse_args()

    from app.bench.sim import bench_garment, bench_motion, sim_overrides
    from core.body.shape import BodyShape
    from core.errors import InputError

    shape = BodyShape()
    try:
        garment = bench_garment(args.garment, 50.0, shape)
        motion = bench_motion(args.motion, args.frames, 0, shape)
        if motion is None:
            raise InputError(f"{args.motion}: clip file not on this machine")
        settings = [(r, k) for r in args.rhos for k in args.iterations]
        result = measure(
            garment, motion, shape, args.frame, args.substeps, settings, args.reference,
            args.linear, sim_overrides(args.overrides),
        )  # fmt: skip
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    result.update(
        garment=args.garment, vertices=garment.num_vertices, motion=args.motion,
        frame=args.frame, substeps=args.substeps, reference_iterations=args.reference,
        linear_iterations=args.linear, overrides=args.overrides,
    )  # fmt: skip
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(
        f"{args.garment} ({garment.num_vertices} vertices), {args.motion} frame {args.frame}, "
        f"{args.substeps} steps, {args.linear} linear iterations; the reference (plain, "
        f"{args.reference} iterations a step) moved the cloth {result['moved_mm']} mm (mean)\n"
    )
    print("| rho | iterations | ms/frame | mean mm | max mm |\n|---:|---:|---:|---:|---:|")
    for r in result["rows"]:
        print(f"| {r['rho']:g} | {r['iterations']} | {r['ms']:.0f} | {r['mean_mm']:.2f} | "
              f"{r['max_mm']:.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
