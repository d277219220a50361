"""Stage ``proxy``: the coarse proxy derived from the target (``proxy/``)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from core.fileio import write_json, write_npz
from core.mesh import load_mesh, save_mesh
from core.project import Project
from core.proxy import ProxyConfig, derive_proxy
from pipeline.config import Log, PipelineConfig, quiet
from templates.garments import make_garment


def stage_proxy(project: Project, config: PipelineConfig, log: Log = quiet) -> dict:
    """The coarse proxy of the target: UV'd ``proxy.obj``, seam-free ``positions.obj``."""
    target = project.path("garment", "target.obj")
    cfg = ProxyConfig(target_verts=config.proxy_verts, texture_size=config.proxy_texture)
    params: dict = {"proxy": asdict(cfg)}
    if config.proxy_template:
        params["template"] = config.proxy_template

    def work(out: Path) -> list[str]:
        mesh, _ = load_mesh(target)
        template = None
        if config.proxy_template:
            template = make_garment(config.proxy_template, shape=config.body)
        result = derive_proxy(mesh, cfg, path=target, template=template)
        save_mesh(out / "proxy.obj", result.proxy)
        save_mesh(out / "positions.obj", result.positions)
        write_npz(out / "seams.npz", seam_map=result.seam_map)
        write_json(out / "report.json", result.report)
        log(
            f"  proxy: {result.positions.num_vertices} vertices "
            f"({result.proxy.num_vertices} with UV seams)"
        )
        return ["proxy.obj", "positions.obj", "seams.npz", "report.json"]

    project.run_stage("proxy", params, [target], work)

    return json.loads(project.path("proxy", "report.json").read_text())
