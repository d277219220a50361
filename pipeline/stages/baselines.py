"""Stage ``baselines``: the comparison methods (Pix2Pix, DNR, DNR with our loss), trained on the
same data set as ours (``baselines/KIND/``)."""

from __future__ import annotations

import json
import time
from pathlib import Path

from core.fileio import write_json
from core.project import Project
from pipeline.config import Log, PipelineConfig, baseline_config, quiet
from pipeline.stages.renderer import plot_losses, read_loss_log
from training.dataset import GarmentDataset, proxy_source_file


def stage_baseline(
    project: Project, config: PipelineConfig, kind: str, log: Log = quiet, progress: bool = True
) -> dict:
    """Train one baseline on the renderer's data set: ``baselines/KIND/`` (model, loss log,
    ``loss.png``, ``report.json``)."""
    import torch

    from training.baselines import train_baseline

    cfg = baseline_config(config, kind)
    source_file = proxy_source_file(project.root, config.renderer_source, config.train_motion.name)
    stage = f"baselines/{kind}"
    params = {"kind": kind, "baseline": cfg.to_dict(), "source": config.renderer_source}

    def work(out: Path) -> list[str]:
        torch.set_num_threads(config.torch_threads)
        data = GarmentDataset(
            project.root, source=config.renderer_source, threads=config.raster_threads
        )
        start = time.perf_counter()
        result = train_baseline(
            kind, data, out, cfg, progress=progress, workers=config.loader_workers
        )
        seconds = time.perf_counter() - start
        rows = read_loss_log(result.log_path)
        plot_losses(rows, out / "loss.png", f"baseline {kind}")
        report = {
            "kind": kind,
            "config": cfg.to_dict(),
            "steps": result.steps,
            "skipped_steps": result.skipped_steps,
            "seconds": seconds,
            "seconds_per_step": seconds / max(result.steps - result.resumed_at_step, 1),
            "first": rows[0] if rows else None,
            "last": rows[-1] if rows else None,
        }
        write_json(out / "report.json", report)
        log(f"  {kind}: {result.steps} steps, {report['seconds_per_step']:.2f} s/step")
        return [result.model_path.name, result.log_path.name, "loss.png", "report.json"]

    inputs = [project.path("dataset", "samples.json"), source_file]
    project.run_stage(stage, params, inputs, work, resumable=[f"{kind}_train.pt"])

    return json.loads(project.path(stage, "report.json").read_text())


def stage_baselines(
    project: Project, config: PipelineConfig, log: Log = quiet, progress: bool = True
) -> dict:
    """Every baseline of ``config.baselines`` (:func:`stage_baseline`), one after another."""
    return {kind: stage_baseline(project, config, kind, log, progress) for kind in config.baselines}
