"""Stage ``videos``: ground truth beside the neural render for each test motion
(``videos/NAME.gif``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from core.fileio import write_json
from core.project import Project
from core.shading import contact_sheet
from pipeline.config import (
    Log,
    PipelineConfig,
    available_test_motions,
    quiet,
)
from pipeline.playback import FrameWriter, Playback, load_motion_for
from pipeline.stages.dataset import lighting_params, project_shading


def stage_videos(project: Project, config: PipelineConfig, log: Log = quiet) -> dict:
    """Side-by-side videos of every test motion: simulated ground truth | neural render of
    Joint2Coarse's proxy, from a camera circling the body once over the clip (unseen views).
    Writes ``videos/MOTION.gif`` and ``report.json`` (ms per frame of the neural path)."""
    import torch

    tests = [m.name for m in available_test_motions(config)]
    inputs = [
        project.path("renderer", "renderer.pt"),
        project.path("joint2coarse", "joint2coarse.pt"),
    ]
    inputs += [project.path(f"sim/{n}-target", "cache.npz") for n in tests]
    params = {"tests": tests, "size": config.image_size, **lighting_params(config)}

    def work(out: Path) -> list[str]:
        torch.set_num_threads(config.torch_threads)
        pb = Playback(project.root, shading=project_shading(config))
        report = {}
        for name in tests:
            pb.set_motion(load_motion_for(project, name))  # a project motion: has its truth
            n = pb.num_frames
            timings = []
            with FrameWriter(out / f"{name}.gif", config.fps) as writer:
                for t in range(n):
                    cam = pb.default_camera(t, config.image_size, config.image_size, 360.0 * t / n)
                    neural = pb.render(t, cam)
                    timings.append(pb.last_timings)
                    truth, label = pb.reference_image(t, cam)
                    scale = max(1, -(-192 // config.image_size))  # tiles big enough for labels
                    tiles = [
                        np.kron(x, np.ones((scale, scale, 1), np.uint8)) for x in (truth, neural)
                    ]
                    writer.append(contact_sheet(tiles, [label, "neural render"], columns=2))
            med = {k: float(np.median([x[k] for x in timings])) for k in timings[0]}
            report[name] = {"frames": n, "median_ms": med}
            log(f"  videos/{name}.gif: {n} frames, neural path {med['total']:.0f} ms/frame median")
        write_json(out / "report.json", report)
        return [*(f"{n}.gif" for n in tests), "report.json"]

    project.run_stage("videos", params, inputs, work)

    return json.loads(project.path("videos", "report.json").read_text())
