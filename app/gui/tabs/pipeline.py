"""The Pipeline tab's controller: run the project's stages (or a fine-tuning) as one job on the
``jobs`` worker, cancellable; progress, time left, log lines, the loss curves and the newest
preview picture (made on the ``plots`` worker)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from PIL import Image

from app.gui.model import (
    Cancelled,
    Eta,
    format_seconds,
    latest_preview,
    loss_plot,
    pipeline_jobs,
    training_logs,
)
from app.gui.part import Part
from app.gui.workers import CancelToken
from core.errors import InputError
from core.project import Project
from pipeline.config import joint2coarse_config, project_config, renderer_config


class PipelineTab(Part):
    """One job at a time; ``studio`` is the :class:`app.gui.controller.Studio` it belongs
    to. The studio's service calls :meth:`update_widgets` while a job runs."""

    def __init__(self, studio):
        super().__init__(studio)
        self.job_name = ""
        self.job_token: CancelToken | None = None
        self.job_eta: Eta | None = None
        self.job_label = ""
        self.job_log: list[str] = []
        self.job_running = False
        self.job_config = None
        self.last_job_result = None
        self._last_plot = 0.0

    def run_pipeline(self, which: str) -> None:
        """Run pipeline stages (``simulate``, ``dataset``, ``joint2coarse``, ``renderer``,
        ``all``, or ``setup``: motions, garment, proxy) on the open project."""
        studio = self.studio
        if studio.project is None:
            studio.show_error(InputError("open a project first"))
            return
        if self.job_running:
            studio.show_error(InputError("a job is already running: cancel it first"))
            return
        try:
            config = project_config(Project(studio.project))
            if which == "setup":
                jobs = pipeline_jobs(config, "all")[:3]
            else:
                jobs = pipeline_jobs(config, which)
        except InputError as exc:
            studio.show_error(exc)
            return
        self.job_config = config
        trains = which in ("joint2coarse", "renderer", "all", "setup")
        self.start_job(which, [(j.label, j.run) for j in jobs], refresh=trains)

    def start_job(
        self, name: str, steps: list, refresh: bool = False, after=None, on_error=None
    ) -> None:
        """Run ``steps`` ((label, run(project, config, log, progress)), ...) in order on the
        jobs worker. Then ``after(result of the last step)`` on the main thread, or with
        ``refresh`` the body list and the project's networks are reloaded; when a step fails
        or is cancelled, ``on_error(exc)`` before the error is shown."""
        studio = self.studio
        project = Project(studio.project)
        config = self.job_config
        token = CancelToken()
        eta = Eta(len(steps))
        self.job_token, self.job_eta, self.job_running = token, eta, True
        self.job_log = []
        self.job_name = name
        self.view.job_label.text = f"{name}: starting"

        def log(message: str) -> None:
            self.job_log.append(message.strip())
            token.check()

        def progress(done: int, total: int) -> None:
            eta.update(done, total)
            token.check()

        def job():
            results = []
            for label, run in steps:
                token.check()
                self.job_label = label
                results.append(run(project, config, log, progress))
                eta.stage_done()
            return results[-1] if results else None

        def done(result) -> None:
            self.job_running = False
            self.last_job_result = result
            self.update_widgets(final=f"{name}: done")
            if after is not None:
                after(result)
            elif refresh and studio.project is not None:
                studio.motion_tab.fill_body_list()
                studio.motion_tab.open_playback(studio.project)

        def failed(exc: BaseException) -> None:
            self.job_running = False
            self.update_widgets(
                final=f"{name}: cancelled" if isinstance(exc, Cancelled) else f"{name}: failed"
            )
            if on_error is not None:
                on_error(exc)
            studio.show_error(exc)

        studio.job_worker.submit(job, done, failed, key="job")

    def cancel(self) -> None:
        """Stop the running job at its next progress report (simulation frames) or between
        stages; a stage stopped half way leaves no record, so it runs again next time."""
        if self.job_token is not None and self.job_running:
            self.job_token.cancel()
            self.view.job_label.text = f"cancelling {self.job_label} ..."

    def _stage_steps(self, label: str) -> int | None:
        try:
            if label == "joint2coarse":
                c = joint2coarse_config(self.job_config)
                return c.autoencoder_steps + c.motion_steps + c.finetune_steps
            if label == "renderer":
                return int(renderer_config(self.job_config).steps)
        except Exception:  # noqa: BLE001 - progress is best effort
            return None
        return None

    def update_widgets(self, final: str | None = None) -> None:
        """Progress bar, stage, time left and log lines; the loss curves and the newest
        preview at most once a second (made on the plots worker)."""
        eta, v = self.job_eta, self.view
        if eta is None:
            return
        root = self.studio.project
        if self.job_running and self.job_label in ("joint2coarse", "renderer"):
            total = self._stage_steps(self.job_label)
            step = _last_step(training_logs(root)[self.job_label])
            if total and step is not None:
                eta.update(step, total)
        v.progress.value = 1.0 if final and "done" in final else eta.progress
        v.job_label.text = final or (
            f"{self.job_name}: {self.job_label} ({min(eta.done + 1, eta.total)}/{eta.total}), "
            f"{eta.progress:.0%}, about {format_seconds(eta.seconds_left())} left"
        )
        v.log_label.text = "\n".join(self.job_log[-3:])[-300:]
        now = time.perf_counter()
        if final or now - self._last_plot > 1.0:
            self._last_plot = now

            def plots():
                loss = loss_plot(training_logs(root), 220, 140)
                preview = latest_preview(root)
                prev = None
                if preview is not None:
                    with Image.open(preview) as im:
                        im = im.convert("RGB")
                        im.thumbnail((220, 140))
                        prev = np.asarray(im)
                return loss, prev

            def show(out) -> None:
                loss, prev = out
                if loss is not None:
                    v.set_image(v.loss_image, loss)
                if prev is not None:
                    v.set_image(v.preview_image, prev)

            self.studio.misc_worker.submit(plots, show, self.studio.show_error, key="plots")


def _last_step(path: Path) -> int | None:
    """The step of the last row of a CSV loss log (None when there is none). Reads only the
    file's last 512 bytes: it runs up to 30 times a second on a growing log, where
    :func:`training.csvlog.read_loss_log` would parse all of it."""
    try:
        with open(path, "rb") as f:
            f.seek(0, 2)
            f.seek(max(f.tell() - 512, 0))
            last = f.read().decode("utf-8", "replace").strip().splitlines()[-1]
        return int(last.split(",")[0])
    except (OSError, IndexError, ValueError):
        return None
