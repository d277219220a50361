"""A project's simulated proxies measured against the body again, from their caches: the
simulation table's hem ratio, waistband drift and hem at end (:func:`core.sim.sanity.band_measures`)
as the code measures them now, beside the figures each clip's report holds (measured by the code
that simulated it).

Usage: ``python benchmarks/sim_bands.py PROJECT [--clip NAME ...] [--json]``

Reads each ``sim/CLIP-proxy/cache.npz`` (its pinned vertices), the proxy as dressed
(``proxy/positions.obj``) and the clip's motion, whose canonical joints give the pelvis (the
hips joint, Spine1 and the feet; within 2 mm of the body as simulated). The hem at end is
measured over the clip's last half second only where the body stands all that while
(:func:`core.sim.sanity.not_standing`); otherwise it is n/a, with the pelvis's largest tilt, the
hips' least height (a share of the rest pose's) and the feet's widest stance over that half
second, which say why.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from core.body.shape import mannequin_skeleton
from core.errors import InputError
from core.mesh import load_mesh
from core.motion.mapping import MAPPED_JOINTS, canonical_positions
from core.project import Project
from core.sim import load_cache
from core.sim.sanity import PELVIS_JOINTS, Pelvis, band_measures
from pipeline.config import project_config
from pipeline.stages.motions import load_project_motion

#: The figures compared, as the simulation reports name them.
FIELDS = ("hem_radius_ratio", "waistband_rise_max_mm", "hem_rise_end_mm")


def measure(project: Project, clips: list[str] | None = None) -> list[dict]:
    """One row per simulated proxy clip (all, or ``clips``): each of :data:`FIELDS` as the clip's
    report holds it (``report_*``) and as measured now, and the end's tilt and hips height."""
    config = project_config(project)
    proxy, _ = load_mesh(project.path("proxy", "positions.obj"))
    skeleton = mannequin_skeleton(config.body)
    rest = skeleton.rest_positions().astype(np.float64)[
        [skeleton.names.index(n) for n in PELVIS_JOINTS]
    ]
    columns = [MAPPED_JOINTS.index(n) for n in PELVIS_JOINTS]
    found = sorted(
        p.parent.name[: -len("-proxy")] for p in project.root.glob("sim/*-proxy/cache.npz")
    )
    if clips:
        missing = sorted(set(clips) - set(found))
        if missing:
            raise InputError(f"no simulated proxy for {', '.join(missing)}", project.root / "sim")
    rows = []
    for clip in clips or found:
        folder = project.stage_dir("sim") / f"{clip}-proxy"
        cache = load_cache(folder / "cache.npz")
        if cache.positions.shape[1] != proxy.num_vertices:
            raise InputError(
                f"{cache.positions.shape[1]} vertices, the proxy has {proxy.num_vertices}",
                folder / "cache.npz",
            )
        joints = canonical_positions(load_project_motion(project, clip))[: cache.num_frames]
        pins = np.asarray(cache.params.get("pinned_indices", []), np.int64)
        bands = band_measures(
            cache.positions, proxy.vertices, proxy.faces, pins,
            Pelvis.of(joints[:, columns], rest), end_frames=max(1, round(0.5 * cache.fps)),
        )  # fmt: skip
        report_path = folder / "report.json"
        stored = json.loads(report_path.read_text()) if report_path.is_file() else {}
        row = {"clip": clip, "frames": int(cache.num_frames)}
        for name in FIELDS:
            row[f"report_{name}"] = stored.get(name)
            row[name] = getattr(bands, name)
        row["end_tilt_deg"] = bands.end_tilt_deg
        row["end_hips_height"] = bands.end_hips_height
        row["end_feet_m"] = bands.end_feet_m
        rows.append(row)
    return rows


def _cell(value, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("project")
    ap.add_argument("--clip", nargs="+", default=None, help="these clips (default: every proxy)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    try:
        rows = measure(Project(args.project), args.clip)
    except InputError as err:
        print(f"benchmarks/sim_bands.py: {err}", file=sys.stderr)
        sys.exit(2)
    command = "python benchmarks/sim_bands.py PROJECT" + (
        " --clip " + " ".join(args.clip) if args.clip else ""
    )
    if args.json:
        print(json.dumps({"command": command, "rows": rows}, indent=1))
        return
    print(
        "| clip | hem ratio: report / now | waistband drift (mm): report / now | "
        "hem at end (mm): report / now | end: pelvis tilt (deg) | end: hips height | "
        "end: feet apart (m) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(
            f"| {r['clip']} | {_cell(r['report_hem_radius_ratio'], '.2f')} / "
            f"{_cell(r['hem_radius_ratio'], '.2f')} | "
            f"{_cell(r['report_waistband_rise_max_mm'], '.0f')} / "
            f"{_cell(r['waistband_rise_max_mm'], '.0f')} | "
            f"{_cell(r['report_hem_rise_end_mm'], '.0f')} / {_cell(r['hem_rise_end_mm'], '.0f')} | "
            f"{_cell(r['end_tilt_deg'], '.0f')} | {_cell(r['end_hips_height'], '.2f')} | "
            f"{_cell(r['end_feet_m'], '.2f')} |"
        )


if __name__ == "__main__":
    main()
