"""Stage ``renderer``: train the neural renderer on the data set (``renderer/``), and the loss
plots of every trained network."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from core.fileio import atomic_path, write_json
from core.project import Project
from pipeline.config import Log, PipelineConfig, quiet, renderer_config
from training.csvlog import read_loss_log
from training.dataset import GarmentDataset, proxy_source_file


def stage_renderer(
    project: Project,
    config: PipelineConfig,
    log: Log = quiet,
    progress: bool = True,
    *,
    stage: str = "renderer",
    overrides: dict | None = None,
) -> dict:
    """Train the neural renderer on the project's data set: ``renderer/``.

    Writes ``renderer.pt`` (load with :func:`training.renderer.train.load_model`), the CSV loss
    log, ``loss.png`` (loss curves), ``previews/step_N.png`` (prediction | ground truth) and
    ``report.json`` (steps, seconds per step, first and last logged losses). A run killed half
    way resumes from its checkpoint. ``stage`` and ``overrides`` (RendererConfig fields) train a
    variant into another folder (the ablations).
    """
    import torch

    from training.renderer.train import train_renderer

    cfg = renderer_config(config).replace(**(overrides or {}))
    train = config.train_motion.name
    source_file = proxy_source_file(project.root, config.renderer_source, train)
    index = project.path("dataset", "samples.json")
    params = {"renderer": cfg.to_dict(), "source": config.renderer_source}
    if not cfg.use_motion:  # its input gained the coverage mask: retrain older ablations
        params["inputs"] = "texture+coverage"

    def work(out: Path) -> list[str]:
        torch.set_num_threads(config.torch_threads)
        data = GarmentDataset(
            project.root, source=config.renderer_source, threads=config.raster_threads
        )
        start = time.perf_counter()
        result = train_renderer(data, out, cfg, progress=progress, workers=config.loader_workers)
        seconds = time.perf_counter() - start
        rows = read_loss_log(result.log_path)
        plot_losses(rows, out / "loss.png", f"neural renderer ({config.renderer_preset}, {stage})")
        report = {
            "config": cfg.to_dict(),
            "source": config.renderer_source,
            "samples": len(data),
            "steps": result.steps,
            "resumed_at_step": result.resumed_at_step,
            "skipped_steps": result.skipped_steps,
            "perceptual": result.perceptual,
            "seconds": seconds,
            "seconds_per_step": seconds / max(result.steps - result.resumed_at_step, 1),
            "first": rows[0] if rows else None,
            "last": rows[-1] if rows else None,
        }
        write_json(out / "report.json", report)
        if rows:
            log(
                f"  {result.steps} steps, L1 {rows[0]['l1']:.4f} -> {rows[-1]['l1']:.4f}, "
                f"{report['seconds_per_step']:.2f} s/step"
            )
        previews = sorted(p.relative_to(out).as_posix() for p in (out / "previews").glob("*.png"))
        return [result.model_path.name, result.log_path.name, "loss.png", "report.json", *previews]

    project.run_stage(
        stage,
        params,
        [index, source_file, project.path("proxy", "proxy.obj")],
        work,
        resumable=["renderer_train.pt"],
    )

    return json.loads(project.path(stage, "report.json").read_text())


def plot_losses(rows: list[dict], path: Path, title: str) -> None:
    """Loss curves (every logged column but bookkeeping) against step, as a PNG, atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    skip = {"step", "epoch", "skipped", "seconds"}
    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=100)
    if rows:
        steps = [r["step"] for r in rows]
        for key in rows[0]:
            if key in skip:
                continue
            ax.plot(steps, [r.get(key, np.nan) for r in rows], label=key)
        ax.set_yscale("symlog", linthresh=1e-2)
        ax.legend(fontsize=7, ncol=3)
    ax.set_xlabel("step")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
