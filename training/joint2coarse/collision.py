"""Collision push-out of predicted proxy vertices against body capsules, and the capsules the
cloth simulation collides with (so a prediction is pushed out of, and measured against, the
same body the simulation saw)."""

from __future__ import annotations

import numpy as np

from core.body.colliders import penetration_depths, posed_garment_capsules
from core.body.shape import BodyShape, mannequin_skeleton
from core.body.skinning import motion_arrays

#: Default distance (metres) kept between a pushed vertex and the capsule surface.
DEFAULT_MARGIN_M = 0.002


def _capsule_fallback(axis: np.ndarray) -> np.ndarray:
    """A unit direction perpendicular to each capsule axis (..., 3); +Y for point capsules."""
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    unit = np.where(norm > 1e-12, axis / np.maximum(norm, 1e-12), 0.0)
    helper = np.where(np.abs(unit[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    perp = np.cross(unit, helper)
    pn = np.linalg.norm(perp, axis=-1, keepdims=True)
    return np.where(pn > 1e-12, perp / np.maximum(pn, 1e-12), [0.0, 1.0, 0.0])


def push_out_of_capsules(
    vertices: np.ndarray,
    capsules: np.ndarray,
    radii: np.ndarray,
    margin: float = DEFAULT_MARGIN_M,
    iterations: int = 2,
) -> np.ndarray:
    """Move vertices that lie inside a capsule (or within ``margin`` of it) onto its surface.

    Each vertex inside goes radially out from its closest point on the capsule axis to
    distance ``radius + margin``. Capsules are applied one after another, ``iterations`` times
    over, so a vertex pushed into a neighbouring capsule is pushed again.

    Parameters
    ----------
    vertices : (T, V, 3) or (V, 3) float
    capsules : (T, K, 2, 3) or (K, 2, 3) float
        Segment end points of each capsule, per frame (the unbatched forms go together).
    radii : (K,) float
    margin : float
        Metres kept outside the surface.
    iterations : int

    Returns
    -------
    Same shape as ``vertices``, float32.
    """
    v = np.asarray(vertices, np.float64)
    caps = np.asarray(capsules, np.float64)
    radii = np.asarray(radii, np.float64)
    single = v.ndim == 2
    if single:
        v, caps = v[None], caps[None]
    if v.ndim != 3 or v.shape[-1] != 3:
        raise ValueError(f"vertices must be (T, V, 3) or (V, 3), got {np.shape(vertices)}")
    if caps.ndim != 4 or caps.shape[0] != v.shape[0] or caps.shape[2:] != (2, 3):
        raise ValueError(
            f"capsules must be ({v.shape[0]}, K, 2, 3) to match vertices, got {np.shape(capsules)}"
        )
    if radii.shape != (caps.shape[1],) or not (radii >= 0).all():
        raise ValueError(f"radii must be ({caps.shape[1]},) and >= 0, got {radii.shape}")
    if not (np.isfinite(caps).all() and np.isfinite(radii).all()):
        raise ValueError("capsules or radii contain NaN or infinite values")
    v = v.copy()
    a, b = caps[:, :, 0], caps[:, :, 1]  # (T, K, 3)
    ab = b - a
    ab2 = np.einsum("tki,tki->tk", ab, ab)
    fallback = _capsule_fallback(ab)
    for _ in range(iterations):
        for k in range(caps.shape[1]):
            ap = v - a[:, k, None]  # (T, V, 3)
            denom = np.where(ab2[:, k] > 1e-24, ab2[:, k], 1.0)[:, None]
            s = np.clip(np.einsum("tvi,ti->tv", ap, ab[:, k]) / denom, 0.0, 1.0)
            closest = a[:, k, None] + s[..., None] * ab[:, k, None]
            d = v - closest
            dist = np.linalg.norm(d, axis=-1)
            target = radii[k] + margin
            inside = dist < target
            if not inside.any():
                continue
            safe = np.maximum(dist, 1e-12)[..., None]
            direction = np.where(dist[..., None] > 1e-12, d / safe, fallback[:, k, None])
            v = np.where(inside[..., None], closest + target * direction, v)
    v = v.astype(np.float32)
    return v[0] if single else v


def simulation_colliders(
    shape: BodyShape,
    motion,
    garment_top: float,
    arm_colliders: bool | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The capsules the cloth simulation collides with, posed for every frame of ``motion``.

    The project's one body collider (:mod:`core.body.colliders`), with the simulation's rule
    for the arms (:func:`core.body.colliders.arms_collide`): they collide only when asked to
    (``arm_colliders``) or, when that is None, when the garment reaches above the chest.

    Parameters
    ----------
    shape : BodyShape
    motion : core.motion.Motion on the mannequin's joints, T frames
    garment_top : float
        Highest rest-pose height (metres) of the garment (the proxy's rest positions).
    arm_colliders : bool or None
        :attr:`core.sim.SimConfig.arm_colliders`.

    Returns
    -------
    ends : (T, K, 2, 3) float32
        Posed capsule end points.
    radii : (K,) float32
    """
    rotations, roots = motion_arrays(mannequin_skeleton(shape), motion)
    return posed_garment_capsules(shape, rotations, roots, garment_top, arm_colliders)


def penetration_summary(positions: np.ndarray, ends: np.ndarray, radii: np.ndarray) -> dict:
    """How far vertices sit inside the body capsules.

    Parameters
    ----------
    positions : (T, V, 3) float
    ends : (T, K, 2, 3) float, radii : (K,) float
        :func:`simulation_colliders`.

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
