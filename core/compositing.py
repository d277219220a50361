"""Swapping the flat clear colour behind a studio render for any backdrop, exactly.

The studio's images are rendered (:mod:`core.shading`) over one known clear colour, averaged in
linear RGB over ``k x k`` ray samples per pixel. Rasterizing the same surfaces from the same
camera at the same ``k x k`` samples gives each pixel's exact surface coverage ``c``
(:func:`surface_coverage`). Since ``pixel = mean(surface samples) + (1 - c) * clear`` in linear
RGB, replacing the clear colour by a backdrop is ``pixel + (1 - c) * (backdrop - clear)``
(:func:`recomposite`): exact up to 8-bit rounding, antialiased edges kept, no colour keying.
Fine-tuning to a new background and playback over a backdrop both use it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from core.camera import resize_camera
from core.color import linear_to_srgb, srgb_to_linear, to_uint8
from core.errors import InputError
from core.raster import MeshScene, RasterConfig


def surface_coverage(
    vertices: np.ndarray, faces: np.ndarray, camera, supersample: int
) -> np.ndarray:
    """Fraction of each pixel's ``k x k`` ray samples that hit the mesh: (H, W) float32.

    Parameters
    ----------
    vertices : (V, 3) float; faces : (F, 3) int
    camera : core.camera.Camera
    supersample : k, as in :class:`core.shading.ShadingConfig` (must match the render's)
    """
    k = int(supersample)
    cam = resize_camera(camera, k * camera.width, k * camera.height)
    frags = MeshScene(vertices, faces).rasterize(cam, RasterConfig())
    hit = (frags.face_id >= 0).astype(np.float32)
    return hit.reshape(camera.height, k, camera.width, k).mean(axis=(1, 3), dtype=np.float32)


def recomposite(
    image: np.ndarray,
    coverage: np.ndarray,
    clear: Sequence[float],
    backdrop: np.ndarray,
) -> np.ndarray:
    """Swap the clear colour behind a render for a backdrop: (H, W, 3) uint8.

    Parameters
    ----------
    image : (H, W, 3) uint8, sRGB, rendered over the flat colour ``clear``
    coverage : (H, W) float in [0, 1], surface coverage of each pixel (:func:`surface_coverage`)
    clear : 3 floats, sRGB in [0, 1] (``ShadingConfig.background``)
    backdrop : (H, W, 3) uint8, sRGB

    Works in linear RGB, where the render averaged its samples; pixels with no coverage are
    the backdrop exactly.
    """
    image = np.asarray(image)
    backdrop = np.asarray(backdrop)
    if image.shape != backdrop.shape or image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"image {image.shape} and backdrop {backdrop.shape} must be (H, W, 3)")
    c = np.clip(np.asarray(coverage, np.float32), 0.0, 1.0)[..., None]
    lin = srgb_to_linear(image.astype(np.float32) / 255)
    back = srgb_to_linear(backdrop.astype(np.float32) / 255)
    lin = lin + (1.0 - c) * (back - srgb_to_linear(np.asarray(clear, np.float32)))
    out = to_uint8(linear_to_srgb(lin))
    empty = c[..., 0] <= 0
    out[empty] = backdrop[empty]
    return out


def fit_image(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Scale ``image`` (H, W, 3) uint8 to cover ``width x height`` and crop the centre."""
    from PIL import Image

    h, w = image.shape[:2]
    if (w, h) == (width, height):
        return image
    s = max(width / w, height / h)
    nw, nh = max(width, round(w * s)), max(height, round(h * s))
    big = np.asarray(Image.fromarray(image).resize((nw, nh), Image.Resampling.LANCZOS))
    x0, y0 = (nw - width) // 2, (nh - height) // 2
    return np.ascontiguousarray(big[y0 : y0 + height, x0 : x0 + width])


def load_image(path: str | os.PathLike) -> np.ndarray:
    """An image file as (H, W, 3) uint8 RGB; InputError naming the file if it is not one."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise InputError("image file not found", path)
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise InputError(f"not a readable image ({exc})", path) from None
