"""The training loop both adversarial trainers run (the neural renderer's and the baselines'):
one step per batch of the feed, a loss row every ``log_every`` steps, a resumable checkpoint
every ``checkpoint_every``, optional previews, and the caller's callback after each step.

A trainer (:class:`Trainer`) brings the parts that differ: its step, its loss row, its preview
and its checkpoint. The loop owns the order of things, so both trainers log, skip, checkpoint
and resume the same way.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Protocol

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
