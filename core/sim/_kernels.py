"""Warp kernels of the simulation (imported only when a simulation runs)."""

from __future__ import annotations

import warp as wp


@wp.kernel
def set_pinned(
    indices: wp.array(dtype=wp.int32),
    targets: wp.array(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    qd: wp.array(dtype=wp.vec3),
):
    """Move pinned particles to their targets (and zero their velocity)."""
    i = wp.tid()
    q[indices[i]] = targets[i]
    qd[indices[i]] = wp.vec3(0.0, 0.0, 0.0)
