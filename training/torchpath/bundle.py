"""A trained project in one file that torch alone can read: what a GPU machine needs to render.

:func:`pipeline.torch_export.export_bundle` writes it from a project (where the whole
studio is installed); :func:`load_bundle` reads it with ``torch.load(weights_only=True)``. The
file holds tensors, numbers, strings, lists and dicts only::

    format        "garment-torch-bundle/1"
    joint2coarse  Joint2Coarse's model payload (config, sizes, state dict)
    renderer      {"config": RendererConfig dict, "generator": state dict}
    proxy         {"faces" (F, 3) int64, "uvs" (Vp, 2) float32, "seam_map" (Vp,) int64}
    body          {"vertices" (Vb, 3) float32 rest, "weights" (Vb, J) float32, "faces" (Fb, 3)}
    rig           {"fov_y_deg", "target_y", "radius"}: the data set's camera framing
    features      {"sigma", "frame_offsets"}
    clips         {name: {"joints" (T, 20, 3) float32, "root_rotations" (T, 3, 3) float32,
                          "root_positions" (T, 3) float64, "transforms" (T, J, 4, 4) float32,
                          "fps" float}}

Clips are motions already on the project's mannequin (forward kinematics and the body's
skinning transforms done at export), so the GPU side needs no BVH reader nor retargeting.
"""

from __future__ import annotations

import os
from pathlib import Path

from core.errors import InputError
from core.fileio import read_torch_payload

#: Format tag of a bundle file.
BUNDLE_FORMAT = "garment-torch-bundle/1"
_KEYS = ("joint2coarse", "renderer", "proxy", "body", "rig", "features", "clips")


def load_bundle(path: str | os.PathLike) -> dict:
    """Read a bundle (see the module docstring); InputError naming the file when it is not one."""
    path = Path(path)
    hint = "no torch bundle here (write one with dng export torch)"
    data = read_torch_payload(path, BUNDLE_FORMAT, "torch bundle", hint)
    missing = [k for k in _KEYS if k not in data]
    if missing:
        raise InputError(f"torch bundle lacks {missing}", path)
    if not data["clips"]:
        raise InputError("torch bundle has no clips", path)
    return data
