"""Body motion: BVH in and out, mapping onto the canonical skeleton, retargeting, procedural clips.

The record is imported eagerly; the functions lazily (``core.motion.load_motion`` works), so
importing the record stays cheap.
"""

from __future__ import annotations

import importlib

from core.motion.motion import Motion

_LAZY = {
    "load_motion": "core.motion.load",
    "resample": "core.motion.load",
    "motion_info": "core.motion.load",
    "read_bvh": "core.motion.bvh",
    "write_bvh": "core.motion.bvh",
    "canonical_positions": "core.motion.mapping",
    "canonical_joints": "core.motion.mapping",
    "retarget": "core.motion.retarget",
    "make_motion": "core.motion.procedural",
    "PROCEDURAL_KINDS": "core.motion.procedural",
}

__all__ = ["Motion", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'core.motion' has no attribute {name!r}")
