"""The detailed target's tiers simulated on a project's embedded target: what ``TierConfig``'s
settings are chosen on.

Usage: ``python benchmarks/tiers.py PROJECT [--clip dance] [--frames 36] [--set KEY=VALUE ...]
[--against KEY=VALUE ...] [--nudge] [--json]``

Reads the project's garment and one clip's embedded target (``sim/CLIP-target/cache.npz`` when
the project embeds it, or re-embedded from ``sim/CLIP-proxy`` when it simulates its tiers), then
simulates the tiers (:func:`core.sim.tiers.simulate_tiers`) over the clip's first ``--frames``
frames with ``TierConfig`` changed by ``--set``, and prints, over the tier vertices (mm, mean /
p95): how far they move from the embedded target ("own dynamics"), their edge stretch (max /
p99 over the garment), the Newton iterations per step and the time per frame.

``--nudge`` also runs the same settings from a 10 um nudge and prints the distance between the
two (the floor). ``--against`` runs a second configuration (``--set``'s, changed by these; e.g.
``--against substeps=4`` for a run twice as fine) and prints the distance between the two: a
setting is converged when that is no more than the floor (docs/decisions.md, "What counts as
converged").
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, replace

import numpy as np

from app.commands import parse_setting
from core.body.colliders import simulation_colliders
from core.errors import InputError
from core.mesh import load_mesh
from core.project import Project
from core.sim import load_cache
from core.sim.embed import BodyContact, drive, load_embedding, strain_stats
from core.sim.sanity import FLOOR_PERTURBATION_M
from core.sim.tiers import TierConfig, distances, find_tiers, simulate_tiers
from pipeline.config import project_config, sim_config
from pipeline.stages.motions import load_project_motion


def _settings(pairs: list[str], base: TierConfig) -> TierConfig:
    values = asdict(base)
    for text in pairs:
        key, value = parse_setting(text)
        if key not in values:
            raise InputError(f"--set {key}: TierConfig has no such field ({', '.join(values)})")
        values[key] = value
    return TierConfig(**values)


def _embedded(project: Project, config, clip: str, frames: int, ends, radii) -> np.ndarray:
    """The clip's target embedded in its simulated proxy, kept out of the body: (T, V, 3)."""
    cache = load_cache(project.path(f"sim/{clip}-target", "cache.npz"))
    if cache.params.get("target_mode", "embed") == "embed":
        return cache.positions[:frames]
    proxy = load_cache(project.path(f"sim/{clip}-proxy", "cache.npz"))
    embedding = load_embedding(project.path("embedding", "embedding.npz"))
    contact = BodyContact(ends[:frames], radii) if config.target_contact else None
    return drive(embedding, proxy.positions[:frames], contact)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project")
    ap.add_argument("--clip", default=None, help="a clip with a target (default: training)")
    ap.add_argument("--frames", type=int, default=36)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--against", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--nudge", action="store_true", help="also the floor (a 10 um nudge)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    try:
        project = Project(args.project)
        config = project_config(project)
        clip = args.clip or config.train_motion.name
        target, _ = load_mesh(project.path("garment", "target.obj"))
        proxy, _ = load_mesh(project.path("proxy", "positions.obj"))
        motion = load_project_motion(project, clip)
        top = float(proxy.vertices[:, 1].max())  # the colliders the stage's target has
        ends, radii = simulation_colliders(
            config.body, motion, top, sim_config(config).arm_colliders
        )
        embedded = _embedded(project, config, clip, args.frames, ends, radii)
        ends = ends[: len(embedded)]
        tiers = find_tiers(target.vertices, target.faces, config.body)
        cfg = _settings(args.set, TierConfig())
        runs = {"run": cfg}
        if args.nudge:
            runs["nudged"] = replace(cfg, perturbation=FLOOR_PERTURBATION_M, seed=1)
        if args.against:
            runs["against"] = _settings(args.against, cfg)
    except InputError as err:
        sys.exit(f"benchmarks/tiers.py: {err}")
    fps = load_cache(project.path(f"sim/{clip}-proxy", "cache.npz")).fps
    out, rows = {}, {}
    for name, c in runs.items():
        positions, run = simulate_tiers(
            embedded, target.faces, target.vertices, tiers, ends, radii, fps, c
        )
        strain = strain_stats(positions, target.vertices, target.faces)
        out[name] = positions
        rows[name] = {
            "settings": {k: v for k, v in asdict(c).items() if v != asdict(TierConfig())[k]},
            "own_dynamics": distances(positions, embedded, tiers.free),
            "stretch_max": strain.stretch_max,
            "stretch_p99": strain.stretch_p99,
            "newton_mean": run.newton_mean,
            "ms_per_frame": 1e3 * run.seconds / len(positions),
        }
    if "nudged" in out:
        rows["floor"] = distances(out["run"], out["nudged"], tiers.free)
    if "against" in out:
        rows["run_vs_against"] = distances(out["run"], out["against"], tiers.free)
    report = {"clip": clip, "frames": len(embedded), "tier_vertices": len(tiers.free), **rows}
    if args.json:
        print(json.dumps(report, indent=2))
        return
    print(f"{clip}, first {len(embedded)} frames, {len(tiers.free)} tier vertices (mm, mean / p95)")
    for name in runs:
        r = rows[name]
        own = r["own_dynamics"]
        print(
            f"  {name:8s} {r['settings'] or 'defaults'}: own dynamics {own['mean_mm']:.1f} / "
            f"{own['p95_mm']:.1f}, stretch {r['stretch_max']:.3f} / {r['stretch_p99']:.3f}, "
            f"{r['newton_mean']:.1f} Newton iterations a step, {r['ms_per_frame']:.0f} ms/frame"
        )
    for name in ("floor", "run_vs_against"):
        if name in rows:
            print(f"  {name}: {rows[name]['mean_mm']:.1f} / {rows[name]['p95_mm']:.1f}")


if __name__ == "__main__":
    main()
