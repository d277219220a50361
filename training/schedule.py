"""Learning-rate schedule shared by the neural renderer and the baselines, and the checks of
the optimiser settings they share.

Constant, then a linear fall to zero: ``decay_from`` is the fraction of a run's steps after
which the rate starts to fall. 1.0 keeps it constant (the paper's Adam at a fixed rate).
The scale depends on the step alone, so a resumed run follows the same schedule.
"""

from __future__ import annotations

import math

import torch

from core.errors import InputError


def check_decay_from(value: object, owner: str) -> None:
    """``InputError`` unless ``value`` is a number in [0, 1]; ``owner`` names the config."""
    if isinstance(value, bool) or not (
        isinstance(value, (int, float)) and math.isfinite(value) and 0.0 <= value <= 1.0
    ):
        raise InputError(f"{owner} config lr_decay_from={value!r} must be a number in [0, 1]")


def check_positive(value: object, owner: str, name: str) -> None:
    """``InputError`` unless ``value`` (``owner``'s setting ``name``: Adam's ``eps``, a
    learning-rate factor) is a finite number > 0."""
    if isinstance(value, bool) or not (
        isinstance(value, (int, float)) and math.isfinite(value) and value > 0
    ):
        raise InputError(f"{owner} config {name}={value!r} must be a finite number > 0")


def lr_scale(step: int, steps: int, decay_from: float) -> float:
    """Factor on the base learning rate at 0-based ``step`` of a ``steps``-step run.

    1 before ``decay_from * steps``; then ``(steps - step) / (steps - start)``, so the last
    step still moves (1 / the decay's length) and the rate would reach 0 one step later.

    >>> [lr_scale(s, 4, 0.5) for s in range(4)]
    [1.0, 1.0, 1.0, 0.5]
    >>> lr_scale(3, 4, 1.0)
    1.0
    """
    start = decay_from * steps
    if step < start or steps - start <= 0:
        return 1.0
    return (steps - step) / (steps - start)


def set_lr(optimizer: torch.optim.Optimizer | None, lr: float) -> None:
    """Set every parameter group's learning rate to ``lr`` times the group's ``lr_scale`` (1
    where it has none; a neural texture's group has ``texture_lr_scale``); no-op without an
    optimiser."""
    if optimizer is not None:
        for group in optimizer.param_groups:
            group["lr"] = lr * group.get("lr_scale", 1.0)
