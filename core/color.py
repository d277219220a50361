"""sRGB and linear RGB, and floats to 8 bits: the colour arithmetic every image shares."""

from __future__ import annotations

import numpy as np


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    c = np.clip(np.asarray(c, np.float32), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055).astype(np.float32)


def to_uint8(c: np.ndarray) -> np.ndarray:
    """[0, 1] floats to uint8 with rounding."""
    return np.clip(np.rint(np.asarray(c, np.float32) * 255.0), 0, 255).astype(np.uint8)
