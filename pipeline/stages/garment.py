"""Stage ``garment``: the detailed target garment (``garment/target.obj``)."""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from core.mesh import load_mesh, save_mesh
from core.project import Project
from core.proxy.pipeline import input_scale
from pipeline.config import Log, PipelineConfig, quiet
from templates.garments import make_garment


def stage_garment(project: Project, config: PipelineConfig, log: Log = quiet) -> Path:
    """The detailed target garment: ``garment/target.obj``."""
    builtin = not Path(config.garment).suffix
    params = {
        "garment": config.garment,
        "resolution_mm": config.garment_resolution_mm,
        "body": asdict(config.body),
    }

    def work(out: Path) -> list[str]:
        if builtin:
            mesh = make_garment(
                config.garment, config.garment_resolution_mm, config.body, config.seed
            )
        else:
            mesh, _ = load_mesh(config.garment)
            # a file in centimetres or millimetres is read as the proxy stage reads it
            scale, unit = input_scale(mesh.vertices, "auto")
            if scale != 1.0:
                mesh = replace(mesh, vertices=(mesh.vertices * scale).astype(np.float32))
                log(f"  {config.garment}: read as {unit} (its size), scaled to metres")
        save_mesh(out / "target.obj", mesh)
        log(f"  {config.garment}: {mesh.num_vertices} vertices, {mesh.num_faces} faces")
        return ["target.obj"]

    project.run_stage("garment", params, [] if builtin else [config.garment], work)
    return project.path("garment", "target.obj")
