"""Stage ``simulate``: the proxy's (and the target's) motion on each clip (``sim/NAME-WHICH/``):
simulated as cloth, or the target embedded in the proxy's simulation; with contact sheets."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from core.body.colliders import penetration_depths, simulation_colliders
from core.body.mannequin import make_body
from core.body.skinning import pose_body
from core.camera import make_camera
from core.errors import InputError
from core.fileio import write_json
from core.mesh import Mesh, load_mesh
from core.project import Project
from core.shading import contact_sheet, render_views, write_png
from core.sim import SimCache, load_cache, save_cache
from core.sim.sanity import FLOOR_PERTURBATION_M
from core.sim.thickness import layer_thickness
from pipeline.config import Log, PipelineConfig, quiet, sim_config
from pipeline.stages.motions import load_project_motion


def stage_simulate(
    project: Project,
    config: PipelineConfig,
    motion_name: str,
    which: str,
    log: Log = quiet,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Simulate the proxy (``which="proxy"``) or the target under a motion of the project.

    The target is simulated, or embedded in the proxy's simulation of the same motion, as
    ``config.target_mode`` says. Writes ``sim/MOTION-WHICH/cache.npz`` and ``report.json``;
    returns the cache's path.
    """
    from core.sim.simulate import simulate

    if which not in ("proxy", "target"):
        raise InputError(f"which must be 'proxy' or 'target', got {which!r}")
    if which == "target" and config.target_mode in ("embed", "tiers"):
        return _embed_target(project, config, motion_name, log)
    garment = (
        project.path("proxy", "positions.obj")
        if which == "proxy"
        else project.path("garment", "target.obj")
    )
    motion_file = project.path("motions", f"{motion_name}.bvh")
    sim_cfg = sim_config(config)
    layered = which == "proxy" and config.layer_thickness
    params = {
        "sim": asdict(sim_cfg),
        "body": asdict(config.body),
        "which": which,
        "layer_thickness": layered,
    }
    stage = f"sim/{motion_name}-{which}"
    inputs = [garment, motion_file] + ([project.path("garment", "target.obj")] if layered else [])

    def work(out: Path) -> list[str]:
        mesh, _ = load_mesh(garment)
        motion = load_project_motion(project, motion_name)
        thickness = proxy_thickness(project, mesh) if layered else None
        cache, report = simulate(
            mesh, motion, config.body, sim_cfg, path=garment, progress=progress,
            thickness=thickness,
        )  # fmt: skip
        save_cache(out / "cache.npz", cache)
        write_json(out / "report.json", asdict(report))
        log(
            f"  {motion_name}/{which}: {cache.num_frames} frames x {cache.num_vertices} vertices, "
            f"{report.ms_per_frame:.0f} ms/frame, penetration {report.penetration_mean_mm:.2f} mm"
        )
        return ["cache.npz", "report.json"]

    project.run_stage(stage, params, inputs, work)
    return project.path(stage, "cache.npz")


def proxy_thickness(project: Project, proxy: Mesh) -> np.ndarray:
    """How deep the project's target (``garment/target.obj``) lies beneath each vertex of its
    ``proxy`` at rest: (Vp,) metres (:func:`core.sim.thickness.layer_thickness`), what the
    proxy's simulation keeps it off the body by (``PipelineConfig.layer_thickness``)."""
    target_file = project.path("garment", "target.obj")
    target, _ = load_mesh(target_file)
    return layer_thickness(proxy.vertices, proxy.faces, target.vertices, target_file)


def stage_embedding(project: Project, config: PipelineConfig, log: Log = quiet) -> Path:
    """The detailed target bound to the proxy at rest (``target_mode="embed"``), which every
    clip's embedded target reads: ``embedding/embedding.npz`` (it depends on the two garments
    alone, not on a motion). Returns its path."""
    from core.sim.embed import FRAME_SMOOTHING_M, SMOOTHING_M, embed, save_embedding

    target_file = project.path("garment", "target.obj")
    proxy_file = project.path("proxy", "positions.obj")
    params = {
        "method": "smoothed-binding-deformation",
        "smoothing_m": SMOOTHING_M,
        "frame_smoothing_m": FRAME_SMOOTHING_M,
    }

    def work(out: Path) -> list[str]:
        target, _ = load_mesh(target_file)
        proxy, _ = load_mesh(proxy_file)
        start = time.perf_counter()
        embedding = embed(target.vertices, proxy.vertices, proxy.faces, target_faces=target.faces)
        save_embedding(out / "embedding.npz", embedding)
        log(
            f"  the target ({target.num_vertices} vertices) bound to the proxy "
            f"({proxy.num_vertices}) in {time.perf_counter() - start:.1f} s"
        )
        return ["embedding.npz"]

    project.run_stage("embedding", params, [target_file, proxy_file], work)
    return project.path("embedding", "embedding.npz")


def _embed_target(project: Project, config: PipelineConfig, motion_name: str, log: Log) -> Path:
    """The target driven by the proxy's simulation (``target_mode="embed"``), with its hanging
    pieces simulated on it (``"tiers"``: :mod:`core.sim.tiers`), measured like a simulation:
    edge stretch and compression against the rest garment, tears, penetration into the body's
    capsules (those the simulation collides with, which ``config.target_contact`` keeps the
    target out of); with tiers, how far they move from the embedded target ("dynamics of
    their own", over the garment and over the tiers), their floor (a 10 um nudge's distance
    over ``TierConfig.floor_frames``) and their crossings of the layer beneath.
    ``sheet.png`` shows the proxy and the target on the body (and the embedded target between
    them, with tiers)."""
    from core.sim.embed import FRAME_SMOOTHING_M, SMOOTHING_M, ContactSettings, strain_stats

    target_file = project.path("garment", "target.obj")
    proxy_file = project.path("proxy", "positions.obj")
    embedding_file = stage_embedding(project, config, log)
    proxy_cache = project.path(f"sim/{motion_name}-proxy", "cache.npz")
    stage = f"sim/{motion_name}-target"
    tiered = config.target_mode == "tiers"
    params = {
        "mode": config.target_mode,
        "method": "smoothed-binding-deformation",
        "smoothing_m": SMOOTHING_M,
        "frame_smoothing_m": FRAME_SMOOTHING_M,
        "body": asdict(config.body),
        "contact": asdict(ContactSettings()) if config.target_contact else None,
    }
    if tiered:
        from core.sim.tiers import TierConfig

        params["tiers"] = asdict(TierConfig())

    def work(out: Path) -> list[str]:
        target, _ = load_mesh(target_file)
        cache = load_cache(proxy_cache)
        motion = load_project_motion(project, motion_name)
        start = time.perf_counter()
        positions, ends, radii = embedded_target(project, config, motion_name)
        rows = [("proxy", cache.positions, cache.faces)]
        extra = {}
        if tiered:
            rows.append(("embedded", positions, target.faces))
            positions, extra = _simulate_tiers(
                positions, target, config.body, ends, radii, cache.fps, log,
            )  # fmt: skip
        seconds = time.perf_counter() - start
        strain = strain_stats(positions, target.vertices, target.faces)
        depth = penetration_depths(positions, ends, radii)
        params_out = {
            **cache.params,
            "target_mode": config.target_mode,
            "proxy_cache": str(proxy_cache),
        }
        save_cache(out / "cache.npz", SimCache(positions, target.faces, cache.fps, params_out))
        rows.append(("target", positions, target.faces))
        _garment_sheet(out / "sheet.png", rows, config.body, motion)
        report = {
            "mode": config.target_mode,
            "frames": int(len(positions)),
            "vertices": int(target.num_vertices),
            "ms_per_frame": 1e3 * seconds / len(positions),
            "strain_max": strain.stretch_max,
            "strain_p99": strain.stretch_p99,
            "compression_max": strain.compression_max,
            "compression_p99": strain.compression_p99,
            "torn_edges": strain.torn_edges,
            "penetration_mean_mm": float(depth.mean() * 1e3),
            "penetration_max_mm": float(depth.max() * 1e3),
            "penetrating_fraction": float((depth > 0).mean()),
            "contact": params["contact"],
            "finite": bool(np.isfinite(positions).all()),
            "sheet": "sheet.png",
            **extra,
        }
        write_json(out / "report.json", report)
        log(
            f"  {motion_name}/target ({'tiers simulated on ' if tiered else ''}embedded in the "
            f"proxy): {report['frames']} frames x "
            f"{report['vertices']} vertices, {report['ms_per_frame']:.1f} ms/frame, stretch max "
            f"{strain.stretch_max:.3f} p99 {strain.stretch_p99:.3f}, "
            f"penetration mean {report['penetration_mean_mm']:.2f} max "
            f"{report['penetration_max_mm']:.1f} mm"
        )
        return ["cache.npz", "report.json", "sheet.png"]

    inputs = [target_file, proxy_file, embedding_file, proxy_cache]
    project.run_stage(stage, params, inputs, work)
    return project.path(stage, "cache.npz")


def embedded_target(
    project: Project, config: PipelineConfig, motion_name: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The detailed target carried by the proxy's simulation of ``motion_name``, every piece
    embedded (no motion of its own; kept out of the body's capsules with
    ``config.target_contact``): what ``target_mode="embed"`` writes, and what ``"tiers"``
    simulates the hanging pieces on.

    Returns positions (T, V, 3) float, and the capsules the simulation collides with: ends
    (T, K, 2, 3) and radii (K,) (:func:`core.body.colliders.simulation_colliders`). Needs the
    binding (``embedding/``, made if missing) and ``sim/MOTION-proxy``.
    """
    from core.sim.embed import BodyContact, drive, load_embedding

    embedding_file = stage_embedding(project, config)
    proxy, _ = load_mesh(project.path("proxy", "positions.obj"))
    cache_file = project.path(f"sim/{motion_name}-proxy", "cache.npz")
    if not cache_file.is_file():
        raise InputError(
            f"no simulation of {motion_name}'s proxy: run the simulate stage", cache_file
        )
    cache = load_cache(cache_file)
    motion = load_project_motion(project, motion_name)
    top = float(proxy.vertices[:, 1].max())
    ends, radii = simulation_colliders(config.body, motion, top, sim_config(config).arm_colliders)
    contact = BodyContact(ends, radii) if config.target_contact else None
    return drive(load_embedding(embedding_file), cache.positions, contact), ends, radii


def _simulate_tiers(embedded, target: Mesh, shape, ends, radii, fps: float, log):
    """The embedded target's tiers simulated (:func:`core.sim.tiers.simulate_tiers`) on the body
    of ``shape``: the positions (T, V, 3) and the report's fields (see :func:`_embed_target`)."""
    from core.sim.tiers import TierConfig, distances, find_tiers, layer_crossings, simulate_tiers

    tiers = find_tiers(target.vertices, target.faces, shape)
    cfg = TierConfig()
    positions, run = simulate_tiers(
        embedded, target.faces, target.vertices, tiers, ends, radii, fps, cfg
    )
    n = min(cfg.floor_frames, len(positions))
    own = {
        "garment": distances(positions, embedded),
        "tiers": distances(positions, embedded, tiers.free),
    }
    fields = {
        "tiers": {
            "pieces": tiers.pieces,
            "vertices": int(len(tiers.free)),
            "seam_vertices": int(len(tiers.pinned)),
            "ms_per_frame": 1e3 * run.seconds / len(positions),
            "newton_mean": run.newton_mean,
            "layer_contact_fraction": run.layer_contacts,
        },
        "own_dynamics": own,
    }
    crossing, deepest = layer_crossings(positions, target.vertices, tiers, cfg)
    fields["tiers"]["layer_crossing_fraction"] = crossing
    fields["tiers"]["layer_crossing_max_mm"] = 1e3 * deepest
    if n:
        nudged = replace(cfg, perturbation=FLOOR_PERTURBATION_M, seed=1)
        again, _ = simulate_tiers(
            embedded[:n], target.faces, target.vertices, tiers, ends[:n], radii, fps, nudged
        )
        fields["floor"] = {
            "frames": n,
            "garment": distances(positions[:n], again),
            "tiers": distances(positions[:n], again, tiers.free),
            "own_dynamics_tiers": distances(positions[:n], embedded[:n], tiers.free),
        }
    floor = fields.get("floor", {}).get("tiers", {}).get("mean_mm")
    log(
        f"    tiers: {tiers.pieces} pieces, {len(tiers.free)} vertices, "
        f"{fields['tiers']['ms_per_frame']:.0f} ms/frame; from the embedded target "
        f"{own['tiers']['mean_mm']:.1f} mm mean (p95 {own['tiers']['p95_mm']:.1f})"
        + ("" if floor is None else f", floor {floor:.1f} mm over {n} frames")
    )
    return positions, fields


def _garment_sheet(path: Path, rows, shape, motion, frames: int = 5) -> None:
    """A contact sheet: one row per garment ``rows`` [(label, positions (T, V, 3), faces
    (F, 3))] on the posed mannequin, at ``frames`` frames spread over the clip (front view)."""
    body = make_body(shape)
    picked = np.linspace(0, len(rows[0][1]) - 1, frames).round().astype(int)
    posed = pose_body(body, motion)
    tiles, labels = [], []
    for label, positions, faces in rows:
        for f in picked:
            centre = motion.root_positions[f].astype(np.float64)
            eye = centre + np.array([0.0, 0.1, 2.6])
            cam = make_camera(eye, centre + np.array([0.0, -0.2, 0.0]), width=192, height=192)
            garment = Mesh(np.asarray(positions[f], np.float32), np.asarray(faces, np.int64))
            (view,) = render_views(garment, Mesh(posed[f], body.faces), [cam])
            tiles.append(view.image)
            labels.append(f"{label} f{f}")
    write_png(path, contact_sheet(tiles, labels, columns=len(picked)))
