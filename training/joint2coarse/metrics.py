"""Per-vertex error of predicted proxies against a reference cache."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class VertexErrors:
    """Euclidean per-vertex error over all frames and vertices, in millimetres."""

    mean_mm: float
    """Mean error."""
    p95_mm: float
    """95th percentile."""
    max_mm: float
    """Largest error."""


def vertex_errors(predicted: np.ndarray, reference: np.ndarray) -> VertexErrors:
    """Compare two caches.

    Parameters
    ----------
    predicted, reference : (T, V, 3) float, metres

    Returns
    -------
    VertexErrors
    """
    p = np.asarray(predicted, np.float64)
    r = np.asarray(reference, np.float64)
    if p.shape != r.shape or p.ndim != 3 or p.shape[-1] != 3 or p.size == 0:
        raise ValueError(
            f"caches must be the same non-empty (T, V, 3), got {p.shape} and {r.shape}"
        )
    e = np.linalg.norm(p - r, axis=-1) * 1000.0
    return VertexErrors(float(e.mean()), float(np.percentile(e, 95)), float(e.max()))
