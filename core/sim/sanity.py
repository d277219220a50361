"""Physical sanity measures of a simulated garment: does the cloth move as cloth does?

Pure functions on position arrays (a :class:`~core.sim.cache.SimCache`'s ``positions``), used by
the sanity tests and by ``dng bench sim``:

* :func:`hem_radius` / :func:`hem_radius_ratio`: the hem's mean distance from the waist's axis,
  against standing (a spin flares a skirt: at 1 rev/s the centripetal acceleration at a 30 cm
  hem, 12 m/s^2, exceeds gravity);
* :func:`hem_lift`: the hem's height below the waist against standing (a jump's fall lifts it);
* :func:`rise_over_hips`: how far a band of the garment (the waistband, the hem) rose along the
  pelvis's up axis against frame 0 (a skirt riding up after a squat or a kick);
* :func:`after_legs_close`: a measure (the hem's rise) a while after each time the feet come
  together and stay (the hem of a real skirt falls back within a second);
* :func:`hem_indices`: the hem, the garment's lowest boundary loop.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from core.errors import InputError
from core.mesh import boundary_loops

#: Default axis of the waist: the vertical (+Y up).
UP = (0.0, 1.0, 0.0)


def hem_indices(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The hem: vertex indices (L,) int64 of the boundary loop with the lowest mean height.

    vertices (V, 3) float rest positions, faces (F, 3) int. ``InputError`` for a closed mesh.
    """
    loops = boundary_loops(faces)
    if not loops:
        raise InputError("garment has no boundary loop: no hem to measure")
    v = np.asarray(vertices, np.float64)
    return min(loops, key=lambda lp: float(v[lp, 1].mean()))


def waist_indices(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The waist (or a top's neckline): vertex indices (L,) int64 of the boundary loop with the
    highest mean height; its centroid is a point of the axis :func:`hem_radius` measures from
    when no pins are known. vertices (V, 3) rest positions, faces (F, 3). ``InputError`` for a
    closed mesh."""
    loops = boundary_loops(faces)
    if not loops:
        raise InputError("garment has no boundary loop: no waist to measure from")
    v = np.asarray(vertices, np.float64)
    return max(loops, key=lambda lp: float(v[lp, 1].mean()))


def _centres(positions: np.ndarray, waist: np.ndarray) -> np.ndarray:
    if len(waist) == 0:
        raise InputError("no waist vertices given: the waist's axis is undefined")
    return np.asarray(positions, np.float64)[:, waist].mean(axis=1)


def hem_radius(positions: np.ndarray, hem: np.ndarray, waist: np.ndarray, axis=UP) -> np.ndarray:
    """Mean distance of the hem from the waist's axis, per frame.

    Parameters
    ----------
    positions : (T, V, 3) float, simulated frames
    hem : (L,) int, hem vertex indices (:func:`hem_indices`)
    waist : (P,) int, waistband vertices (a simulation's pinned vertices): their centroid at
        each frame is a point of the axis
    axis : (3,) or (T, 3) float, the axis direction (default vertical)

    Returns
    -------
    (T,) float64, metres
    """
    p = np.asarray(positions, np.float64)
    c = _centres(p, waist)
    a = np.broadcast_to(np.asarray(axis, np.float64), c.shape)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    d = p[:, hem] - c[:, None]
    radial = d - (d * a[:, None]).sum(-1, keepdims=True) * a[:, None]
    return np.linalg.norm(radial, axis=-1).mean(axis=1)


def hem_radius_ratio(
    positions: np.ndarray, hem: np.ndarray, waist: np.ndarray, axis=UP, start: float = 0.5
) -> float:
    """Mean hem radius over the clip's tail (frames from ``start`` x T on) over frame 0's.

    Frame 0 is the garment settled on the standing body (the simulation's lead-in ends there).
    Shapes as :func:`hem_radius`. Above 1: the hem flared out; below 1: it closed in.
    """
    r = hem_radius(positions, hem, waist, axis)
    if len(r) < 2:
        raise InputError(f"need at least 2 frames to compare with frame 0, got {len(r)}")
    return float(r[int(start * len(r)) :].mean() / r[0])


def hem_lift(positions: np.ndarray, hem: np.ndarray, waist: np.ndarray) -> np.ndarray:
    """How far the hem rose towards the waist since frame 0, per frame (metres, (T,) float64).

    The hem's mean height minus the waist's (centroid of ``waist``), against frame 0's: positive
    when the hem hangs higher under the waist than standing (a fall lifts it, a landing drops
    it). Shapes as :func:`hem_radius`.
    """
    p = np.asarray(positions, np.float64)
    rel = p[:, hem, 1].mean(axis=1) - _centres(p, waist)[:, 1]
    return rel - rel[0]


def rise_over_hips(
    positions: np.ndarray, band: np.ndarray, hips: np.ndarray, up: np.ndarray
) -> np.ndarray:
    """How far a band of vertices rose along the pelvis's up axis since frame 0, relative to
    the hips joint, per frame (metres, (T,) float64): the waistband of a skirt that rides up
    climbs the torso; its hem, bunched over the hips, stays up when the body stands again.

    positions (T, V, 3) float; band (B,) int; hips (T, 3) float the hips joint; up (T, 3)
    float the pelvis's up direction (hips to the spine above it; normalised here).
    """
    p = np.asarray(positions, np.float64)
    h = np.asarray(hips, np.float64)
    u = np.asarray(up, np.float64)
    if p.ndim != 3 or h.shape != (len(p), 3) or u.shape != (len(p), 3) or not len(band):
        raise InputError(
            f"need positions (T, V, 3), hips and up (T, 3) and a band: got {p.shape}, "
            f"{h.shape}, {u.shape}, {len(band)} vertices"
        )
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    height = np.einsum("tbk,tk->t", p[:, band] - h[:, None], u) / len(band)
    return height - height[0]


def after_legs_close(
    values: np.ndarray, feet: np.ndarray, fps: float, delay_s: float = 1.0, apart_m: float = 0.3
) -> np.ndarray:
    """``values`` (T,) (a band's :func:`rise_over_hips`) ``delay_s`` after each frame at which
    the feet come within ``apart_m`` of each other, having been farther apart the frame before,
    and stay so for ``delay_s``: (E,) float64, one per such closing (none: empty).

    feet : (T, 2, 3) float the left and right foot joints.
    """
    v = np.asarray(values, np.float64)
    f = np.asarray(feet, np.float64)
    if v.ndim != 1 or f.shape != (len(v), 2, 3) or fps <= 0 or delay_s < 0:
        raise InputError(
            f"need values (T,) and feet (T, 2, 3) with fps > 0: got {v.shape}, {f.shape}, {fps}"
        )
    close = np.linalg.norm(f[:, 0] - f[:, 1], axis=1) < apart_m
    wait = int(round(delay_s * fps))
    starts = [
        i for i in range(1, len(v) - wait)
        if close[i] and not close[i - 1] and close[i : i + wait + 1].all()
    ]  # fmt: skip
    return v[np.asarray(starts, np.int64) + wait] if starts else np.zeros(0)


#: Standard deviation (metres) of the random displacement of a rest garment that measures a
#: simulation's floor: how far the cloth's own sensitivity alone moves it (``dng bench sim
#: --floor``, ``dng eval joint2coarse --floor``).
FLOOR_PERTURBATION_M = 1e-5


def perturbed(garment, sigma: float, seed: int):
    """``garment`` with every vertex moved by a normal random offset of ``sigma`` metres per axis
    (a seeded generator: the same offsets every run)."""
    rng = np.random.default_rng(seed)
    moved = garment.vertices + sigma * rng.standard_normal(garment.vertices.shape)
    return replace(garment, vertices=moved.astype(np.float32))
