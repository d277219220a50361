"""Small numeric helpers on arrays shared by every layer."""

from __future__ import annotations

import numpy as np


def smoothstep(x: np.ndarray | float, lo: float = 0.0, hi: float = 1.0) -> np.ndarray:
    """C1 ramp: 0 at and below ``lo``, 1 at and above ``hi``, ``3u^2 - 2u^3`` in between.

    Parameters
    ----------
    x : (...) float
    lo, hi : float, ``lo < hi``

    Returns
    -------
    (...) float64, the shape of ``x``.
    """
    u = np.clip((np.asarray(x, np.float64) - lo) / (hi - lo), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)
