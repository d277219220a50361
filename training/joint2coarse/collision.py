"""The capsules the cloth simulation collides with, posed for a motion, and how far a prediction
sits inside them (so a prediction is pushed out of, with
:func:`core.body.colliders.push_out_of_capsules`, and measured against the same body the
simulation saw)."""

from __future__ import annotations

import numpy as np

from core.body.colliders import penetration_depths, posed_garment_capsules
from core.body.shape import BodyShape, mannequin_skeleton
from core.body.skinning import motion_arrays


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
