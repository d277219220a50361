"""Cloth simulation speed on CPU: newton's Style3D as shipped against ours (before / after).

Usage: ``python benchmarks/sim_speed.py [--resolution 50] [--frames 20] [--motion dance]
[--settings 2,16 8,16 16,32]``

Simulates the ``long-skirt`` template (50 mm: about 1k vertices, a proxy's size) under a
procedural clip, once per setting (substeps,iterations) and way: ``newton`` (its PCG, five
kernel launches per conjugate-gradient iteration, every launch packed anew) and ``ours``
(:mod:`core.sim.simulate`: each linear solve one launch of ``pcg_serial``, the solver's other
launches recorded once and replayed). Prints wall ms per clip frame and the load average (on a
shared machine other processes inflate every figure; compare rows taken together).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys


def run_once(garment, motion, shape, substeps: int, iterations: int, ours: bool) -> float:
    import warp as wp
    from newton._src.solvers.style3d import solver_style3d
    from newton._src.solvers.style3d.collision import collision

    from core.sim import simulate as sim
    from core.sim.config import SimConfig
    from core.sim.style3d import AcceleratedStep

    # Plain iterations both ways (the acceleration costs one small kernel an iteration).
    cfg = SimConfig(
        substeps=substeps, iterations=iterations, transition_s=0.2, settle_s=0.1, chebyshev_rho=0
    )
    saved = sim._Scene._serial_pcg, sim._record_style3d_launches, AcceleratedStep.__call__
    if not ours:  # newton's own: its step, no serial PCG, no recorded launches
        sim._Scene._serial_pcg = lambda self: None
        sim._record_style3d_launches = lambda wp_: None
        solver_style3d.wp = collision.wp = wp
        AcceleratedStep.__call__ = lambda self, s_in, s_out, contacts, dt: self.solver.step(
            s_in, s_out, None, contacts, dt
        )
    try:
        with contextlib.redirect_stdout(sys.stderr):
            _, report = sim.simulate(garment, motion, shape, cfg)
    finally:
        sim._Scene._serial_pcg, sim._record_style3d_launches, AcceleratedStep.__call__ = saved
    return report.ms_per_frame


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=float, default=50.0, help="long-skirt edge, mm")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--motion", default="dance")
    parser.add_argument("--settings", nargs="+", default=["2,16", "8,16", "16,32"])
    args = parser.parse_args()

    from core.body.shape import BodyShape
    from core.motion.procedural import make_motion
    from templates.garments import make_garment

    shape = BodyShape()
    garment = make_garment("long-skirt", args.resolution, shape=shape)
    motion = make_motion(args.motion, args.frames, 30.0, 0, shape)
    print(f"long-skirt, {garment.num_vertices} vertices, {args.motion}, {args.frames} frames")
    for text in args.settings:
        s, i = (int(x) for x in text.split(","))
        for ours in (False, True):
            ms = run_once(garment, motion, shape, s, i, ours)
            way = "ours" if ours else "newton"
            load = os.getloadavg()[0]
            print(f"{s:2d} x {i:<2d} {way:6s} {ms:8.1f} ms/frame  (load {load:.1f})", flush=True)


if __name__ == "__main__":
    main()
