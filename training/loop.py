"""The training loop the adversarial trainer runs (:mod:`training.adversarial`: the neural
renderer's and every baseline's): one step per batch of the feed, a loss row every
``log_every`` steps, a resumable checkpoint every ``checkpoint_every``, optional previews, and
the caller's callback after each step.

:class:`AdversarialRun` is the state a run keeps and checkpoints (the sample order, the step,
skipped steps, loss sums between log rows, rows not yet written, the elapsed time), its loss
row and the checks a resumed checkpoint must pass (:func:`read_checkpoint`, also Joint2Coarse's).
:class:`training.adversarial.AdversarialTrainer` subclasses it with the networks, the step and
the checkpoint's contents. The loop owns the order of things, so every method logs, skips,
checkpoints and resumes the same way.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Protocol

import torch

from core.errors import InputError
from core.fileio import read_torch_payload
from training.loader import SampleOrder


class Trainer(Protocol):
    """What :func:`run_steps` drives."""

    step: int
    skipped: int
    count: int
    sums: dict[str, float]
    order: SampleOrder

    def train_step(self, batch) -> dict[str, float] | None: ...

    def log_row(self) -> dict[str, float]: ...

    def save_checkpoint(self) -> None: ...


class AdversarialRun:
    """What an adversarial run keeps, logs and checkpoints.

    Parameters
    ----------
    n_samples, seed : the data set's length and the run's seed (the order's generator is seeded
        by ``seed + 1``, as it always was)
    losses : the loss names, in the log's column order (``step``, ``epoch``, the losses,
        ``skipped``, ``seconds``)
    """

    def __init__(self, n_samples: int, seed: int, losses: tuple[str, ...]):
        self.order = SampleOrder.start(n_samples, seed + 1)
        self.step = self.skipped = self.count = self.resumed_at_step = 0
        self.losses = losses
        self.sums = dict.fromkeys(losses, 0.0)
        self.pending_rows: list[list] = []
        self.t0 = time.perf_counter()
        self.elapsed = 0.0

    def off_losses(self) -> set[str]:
        """Losses this run does not compute (logged as ``off``)."""
        return set()

    def log_row(self) -> dict[str, float]:
        """Queue a log row of the loss means since the last one; returns the means."""
        n = max(self.count, 1)
        means = {k: v / n for k, v in self.sums.items()}
        off = self.off_losses()
        row: list = [self.step, self.order.epoch]
        for k in self.losses:
            if self.count == 0:
                row.append("")
            elif k in off:
                row.append("off")
            else:
                row.append(f"{means[k]:.6g}")
        row += [self.skipped, f"{self.seconds():.1f}"]
        self.pending_rows.append(row)
        self.sums = dict.fromkeys(self.sums, 0.0)
        self.count = 0
        return means

    def seconds(self) -> float:
        """Training time of the run so far, resumed runs included."""
        return self.elapsed + time.perf_counter() - self.t0

    def run_state(self) -> dict:
        """The checkpoint's fields of this state (with the process's torch RNG)."""
        return {
            "step": self.step,
            "epoch": self.order.epoch,
            "perm": self.order.perm,
            "pos": self.order.pos,
            "skipped": self.skipped,
            "sums": self.sums,
            "count": self.count,
            "elapsed": self.seconds(),
            "torch_rng": torch.get_rng_state(),
            "shuffle_rng": self.order.rng,
        }

    def restore_run_state(self, payload: dict) -> None:
        """Inverse of :meth:`run_state` (sets the process's torch RNG)."""
        self.step = self.resumed_at_step = int(payload["step"])
        self.order = SampleOrder(
            payload["perm"], int(payload["pos"]), int(payload["epoch"]), payload["shuffle_rng"]
        )
        self.skipped = int(payload["skipped"])
        self.sums = dict(payload["sums"])
        self.count = int(payload["count"])
        self.elapsed = float(payload["elapsed"])
        torch.set_rng_state(payload["torch_rng"])


def read_checkpoint(path: Path, fmt: str, what: str, expected: list[tuple[str, object, str]]):
    """A trainer's checkpoint (:func:`core.fileio.read_torch_payload`), after checking that each
    ``(key, value, what differs)`` of ``expected`` matches; InputError naming the file otherwise
    (the run then needs a new folder)."""
    payload = read_torch_payload(path, fmt, f"{what} training checkpoint")
    for key, mine, differs in expected:
        if payload.get(key) != mine:
            raise InputError(
                f"checkpoint was made with {differs}: use a new folder or delete it", path
            )
    return payload


def run_steps(
    tr: Trainer,
    feed: Iterable[tuple[object, SampleOrder]],
    n_steps: int,
    bar,
    *,
    name: str,
    log_every: int,
    checkpoint_every: int,
    postfix: Callable[[dict[str, float]], dict],
    preview_every: int = 0,
    preview: Callable[[], None] | None = None,
    callback: Callable[[int, dict[str, float] | None], None] | None = None,
    say: Callable[[str], None] | None = None,
) -> None:
    """Train ``tr`` up to step ``n_steps`` on ``feed`` (``(batch, order after it)`` pairs, from
    :func:`training.loader.batches`), then write its last checkpoint.

    ``bar`` is a tqdm bar (its postfix from ``postfix(means)`` at every log row); ``say`` prints
    a line (a skipped step; None: silent, as a rank other than 0); ``preview`` runs every
    ``preview_every`` steps and at the end; ``callback(step, losses or None)`` after each step
    (raising from it stops the run, which resumes from the last checkpoint).
    """
    for batch, order in feed:
        tr.order = order
        losses = tr.train_step(batch)
        tr.step += 1
        if losses is None:
            tr.skipped += 1
            if say is not None:
                say(f"{name}: step {tr.step} skipped (non-finite loss or gradient)")
        else:
            for k, v in losses.items():
                tr.sums[k] += v
            tr.count += 1
        done = tr.step == n_steps
        if tr.step % log_every == 0 or done:
            bar.set_postfix(postfix(tr.log_row()), refresh=False)
        if preview is not None and preview_every and (tr.step % preview_every == 0 or done):
            preview()
        bar.update(1)
        if not done and tr.step % checkpoint_every == 0:
            tr.save_checkpoint()
        if callback is not None:
            callback(tr.step, losses)
    tr.save_checkpoint()
