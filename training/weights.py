"""Loading a network's weights from a file the user gives (FID's Inception, tLP's LPIPS): one
set of checks, each failure an :class:`InputError` that names the file."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import torch
from torch import nn

from core.errors import InputError


def read_state_dict(path: str | os.PathLike, what: str) -> tuple[dict, Path]:
    """The state dict (name -> tensor) in the file ``path``, and the path; ``what`` names the
    weights in the errors (``"Inception"``: "Inception weights file not found")."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} weights file not found", path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise InputError(f"cannot read {what} weights: {exc}", path) from None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(f"{what} weights file must hold a state dict of tensors", path)
    return state, path


def load_state(
    net: nn.Module,
    state: dict,
    path: Path,
    layout: str,
    optional: Callable[[str], bool] = lambda name: False,
    note: str = "",
) -> nn.Module:
    """``net`` with ``state`` loaded into it, every entry checked: an entry of ``net`` missing
    from ``state`` (unless ``optional(name)``), one ``net`` does not have, or one of another
    shape raises :class:`InputError` naming ``path`` (``layout``: what the file should be, e.g.
    ``"a torchvision InceptionV3"``; ``note``: added to a shape's error, e.g. the width).
    Returns ``net`` in eval mode."""
    own = net.state_dict()
    missing = [k for k in own if k not in state and not optional(k)]
    unexpected = [k for k in state if k not in own]
    if missing or unexpected:
        raise InputError(
            f"not {layout} state dict: missing {missing[:3]} (of {len(missing)}), unexpected "
            f"{unexpected[:3]} (of {len(unexpected)})",
            path,
        )
    for k, v in state.items():
        if tuple(v.shape) != tuple(own[k].shape):
            raise InputError(
                f"{k} has shape {tuple(v.shape)}, expected {tuple(own[k].shape)}{note}", path
            )
    own.update({k: v.to(own[k].dtype) for k, v in state.items()})
    net.load_state_dict(own)
    return net.eval()
