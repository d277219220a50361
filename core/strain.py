"""Edges held to a stretch: the shortening the embedded target's contact step runs
(:mod:`core.sim.embed`) and the strain limit Joint2Coarse's predictions keep
(:func:`training.joint2coarse.prediction_stretch_limit`). Numpy only: the torch render path
imports it (:mod:`training.torchpath`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InputError
from core.mesh import unique_edges


def shorten_edges(
    x: np.ndarray, edges: np.ndarray, limit: np.ndarray, movable: np.ndarray
) -> np.ndarray:
    """Shorten ``edges`` (E, 2) of ``x`` (V, 3) longer than ``limit`` (E,) back to it (in place):
    both ends alike where both are ``movable`` (V,) bool, else the movable end alone; each vertex
    by the mean of its edges' corrections. Every edge needs a movable end. Returns the indices
    of the vertices moved."""
    vec = x[edges[:, 1]] - x[edges[:, 0]]
    length = np.linalg.norm(vec, axis=1)
    over = np.flatnonzero(length > limit)
    if not len(over):
        return over
    ends = edges[over]
    m0, m1 = movable[ends[:, 0]], movable[ends[:, 1]]
    share = 1.0 / (m0.astype(np.float64) + m1)
    step = (1.0 - limit[over] / length[over])[:, None] * vec[over]
    count = np.bincount(ends[:, 0], m0, len(x)) + np.bincount(ends[:, 1], m1, len(x))
    shift = np.stack(
        [
            np.bincount(ends[:, 0], m0 * share * step[:, k], len(x))
            - np.bincount(ends[:, 1], m1 * share * step[:, k], len(x))
            for k in range(3)
        ],
        axis=1,
    )
    hit = np.flatnonzero(count)
    x[hit] += shift[hit] / count[hit, None]
    return hit


@dataclass(frozen=True)
class StretchLimit:
    """How far a cloth's edges may stretch (:func:`limit_stretch`).

    Attributes
    ----------
    edges : (E, 2) int64 the mesh's edges
    lengths : (E,) float64 their rest lengths (metres)
    limit : stretch (``len / rest - 1``) an edge may keep
    sweeps : most shortening sweeps (each moves an edge's excess one edge along the cloth)
    """

    edges: np.ndarray
    lengths: np.ndarray
    limit: float
    sweeps: int


def stretch_limit(rest: np.ndarray, faces: np.ndarray, limit: float, sweeps: int) -> StretchLimit:
    """The :class:`StretchLimit` of a mesh: ``rest`` (V, 3) its rest positions, ``faces`` (F, 3)."""
    if not (np.isfinite(limit) and limit >= 0) or int(sweeps) < 1:
        raise InputError(f"need a stretch limit >= 0 and sweeps >= 1, got {limit}, {sweeps}")
    edges = unique_edges(np.asarray(faces, np.int64))
    r = np.asarray(rest, np.float64)
    lengths = np.linalg.norm(r[edges[:, 1]] - r[edges[:, 0]], axis=1)
    return StretchLimit(edges, lengths, float(limit), int(sweeps))


def limit_stretch(positions: np.ndarray, s: StretchLimit) -> np.ndarray:
    """``positions`` (T, V, 3) or (V, 3) with every edge longer than ``1 + s.limit`` times its rest
    length shortened back, both ends alike (each vertex by the mean of its edges' corrections:
    :func:`shorten_edges`), ``s.sweeps`` times or until none is: a strain limit, as cloth solvers
    project one. Returns float64 of the same shape; frames are independent."""
    p = np.asarray(positions, np.float64)
    t, v = (1, p.shape[0]) if p.ndim == 2 else p.shape[:2]
    x = p.reshape(t * v, 3).copy()
    edges = s.edges[None] + v * np.arange(t)[:, None, None]  # (T, E, 2) into the frames
    limit = (1.0 + s.limit) * s.lengths
    movable = np.ones(len(x), bool)
    active = np.arange(t)  # frames with an edge still over its limit
    for _ in range(s.sweeps):
        hit = shorten_edges(x, edges[active].reshape(-1, 2), np.tile(limit, len(active)), movable)
        if not len(hit):
            break
        active = np.unique(hit // v)
    return x.reshape(p.shape)
