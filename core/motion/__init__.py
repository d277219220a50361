"""Body motion: BVH in and out, mapping onto the canonical skeleton, retargeting, procedural clips."""

from core.motion.motion import Motion

__all__ = ["Motion"]
