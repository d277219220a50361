"""How far a prediction sits inside the capsules the cloth simulation collides with
(:func:`core.body.colliders.simulation_colliders`; a prediction is pushed out of them with
:func:`core.body.colliders.push_out_of_capsules`, and measured against the same body the
simulation saw)."""

from __future__ import annotations

import numpy as np

from core.body.colliders import penetration_depths


def penetration_summary(positions: np.ndarray, ends: np.ndarray, radii: np.ndarray) -> dict:
    """How far vertices sit inside the body capsules.

    Parameters
    ----------
    positions : (T, V, 3) float
    ends : (T, K, 2, 3) float, radii : (K,) float
        :func:`core.body.colliders.simulation_colliders`.

    Returns
    -------
    dict: ``inside_percent`` (vertex-frames inside, %), ``mean_mm`` (mean depth over all
    vertex-frames, 0 outside), ``max_mm`` (deepest).
    """
    depth = penetration_depths(np.asarray(positions), ends, radii)
    return {
        "inside_percent": float(100.0 * (depth > 0).mean()),
        "mean_mm": float(depth.mean() * 1e3),
        "max_mm": float(depth.max() * 1e3),
    }
