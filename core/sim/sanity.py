"""Physical sanity measures of a simulated garment: does the cloth move as cloth does?

Pure functions on position arrays (a :class:`~core.sim.cache.SimCache`'s ``positions``), used by
the sanity tests and by ``dng bench sim``:

* :func:`hem_radius` / :func:`hem_radius_ratio`: the hem's mean distance from the waist's axis,
  against standing (a spin flares a skirt: at 1 rev/s the centripetal acceleration at a 30 cm
  hem, 12 m/s^2, exceeds gravity);
* :func:`hem_lift`: the hem's height below the waist against standing (a jump's fall lifts it);
* :func:`band_height` / :func:`rise_over_hips`: a band of the garment's (the waistband's, the
  hem's) height along the pelvis's up axis above the hips joint, and its rise against frame 0
  (a skirt riding up after a squat or a kick);
* :func:`not_standing`: whether the body stood through a while (pelvis near upright, hips
  near their standing height, feet not wide apart), where a hem's height along the pelvis says
  whether the skirt rode up and not how the body bends or crouches;
* :func:`after_legs_close`: a measure (the hem's rise) a while after each time the feet come
  together and stay (the hem of a real skirt falls back within a second);
* :func:`band_measures`: a simulation report's waistband and hem figures
  (:class:`BandMeasures`) from its positions and the body's :class:`Pelvis`;
* :func:`hem_indices`: the hem, the garment's lowest boundary loop.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

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
    positions: np.ndarray,
    hem: np.ndarray,
    waist: np.ndarray,
    axis=UP,
    start: float = 0.5,
    reference: float | None = None,
) -> float:
    """Mean hem radius over the clip's tail (frames from ``start`` x T on) over ``reference``
    (metres), by default frame 0's.

    Frame 0 is the garment settled on the body in the clip's first pose (the simulation's
    lead-in ends there): standing for a procedural clip, but not for a window cut from a
    capture, whose body may be bent over there (its hem then hangs far from the waist's
    vertical axis). The simulation report passes the radius of the garment as dressed.
    Shapes as :func:`hem_radius`. Above 1: the hem flared out; below 1: it closed in.
    """
    r = hem_radius(positions, hem, waist, axis)
    if len(r) < 2:
        raise InputError(f"need at least 2 frames to compare with frame 0, got {len(r)}")
    return float(r[int(start * len(r)) :].mean() / (r[0] if reference is None else reference))


def hem_lift(positions: np.ndarray, hem: np.ndarray, waist: np.ndarray) -> np.ndarray:
    """How far the hem rose towards the waist since frame 0, per frame (metres, (T,) float64).

    The hem's mean height minus the waist's (centroid of ``waist``), against frame 0's: positive
    when the hem hangs higher under the waist than standing (a fall lifts it, a landing drops
    it). Shapes as :func:`hem_radius`.
    """
    p = np.asarray(positions, np.float64)
    rel = p[:, hem, 1].mean(axis=1) - _centres(p, waist)[:, 1]
    return rel - rel[0]


def band_height(
    positions: np.ndarray, band: np.ndarray, hips: np.ndarray, up: np.ndarray
) -> np.ndarray:
    """A band of vertices' mean height along the pelvis's up axis above the hips joint, per
    frame (metres, (T,) float64; a skirt's hem is below: negative).

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
    return np.einsum("tbk,tk->t", p[:, band] - h[:, None], u) / len(band)


def rise_over_hips(
    positions: np.ndarray, band: np.ndarray, hips: np.ndarray, up: np.ndarray
) -> np.ndarray:
    """How far a band of vertices rose along the pelvis's up axis since frame 0, relative to
    the hips joint, per frame (metres, (T,) float64): the waistband of a skirt that rides up
    climbs the torso; its hem, bunched over the hips, stays up when the body stands again.
    Shapes as :func:`band_height`.
    """
    height = band_height(positions, band, hips, up)
    return height - height[0]


#: When the body counts as standing (:func:`not_standing`): the pelvis's up axis at most this many
#: degrees from the vertical, the hips at least this share of the rest pose's height above the
#: lower foot, and the feet at most this far apart (metres). Over the last half second of quick
#: run q72's clips, a walk's or an idle's pelvis tilts 3 to 13 degrees, its hips stay at 0.88 to
#: 0.97 and its feet come at most 0.64 m apart (a boxer's stance, a stride); a bend over reaches
#: 47 to 67 degrees, a landing's crouch 0.41 to 0.72, the squat's wide stance 0.78 m
#: (docs/decisions.md, "Hem at end").
STANDING_TILT_DEG = 30.0
STANDING_HEIGHT_SHARE = 0.85
STANDING_FEET_M = 0.7


def pelvis_tilt(up: np.ndarray) -> np.ndarray:
    """The angle (degrees, (T,) float64) of each of ``up`` (T, 3) (the pelvis's up direction, any
    length) from the vertical (+Y)."""
    u = np.asarray(up, np.float64)
    cos = u[:, 1] / np.linalg.norm(u, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def not_standing(tilt_deg: float, hips_height: float, feet_m: float) -> str | None:
    """What rules out that a body stood all through a while, from its worst figures over it:
    the pelvis's largest tilt from the vertical (degrees), the hips' least height above the
    lower foot as a share of the rest pose's, the feet's widest stance (metres). None when it
    stood: the tilt at most ``STANDING_TILT_DEG``, the hips at least ``STANDING_HEIGHT_SHARE``,
    the feet at most ``STANDING_FEET_M`` apart. Else ``"pelvis 67 deg"``, ``"hips at 0.41"`` or
    ``"feet 0.78 m apart"`` (the first that fails). A hem's height along the pelvis measures a
    skirt riding up only where the body stands: bent over, a hem hanging straight down sits
    high along the tilted pelvis; crouched, the thighs lift it; in a wide stance, the legs
    spread it."""
    if tilt_deg > STANDING_TILT_DEG:
        return f"pelvis {tilt_deg:.0f} deg"
    if hips_height < STANDING_HEIGHT_SHARE:
        return f"hips at {hips_height:.2f}"
    if feet_m > STANDING_FEET_M:
        return f"feet {feet_m:.2f} m apart"
    return None


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


#: The joints a :class:`Pelvis` is made of, in its order.
PELVIS_JOINTS = ("Hips", "Spine1", "LeftFoot", "RightFoot")


@dataclass(frozen=True)
class Pelvis:
    """The body's pelvis and feet at every clip frame and at rest: what a garment's waistband
    and hem are measured against (:func:`band_measures`).

    Attributes
    ----------
    hips : (T, 3) float64 the hips joint
    up : (T, 3) float64 hips to Spine1 (not normalised)
    feet : (T, 2, 3) float64 the left and right foot joints
    rest_hips, rest_up : (3,) float64 the same at the rest pose (the garment's as dressed)
    standing_height : the rest pose's hips above its lower foot (metres)
    """

    hips: np.ndarray
    up: np.ndarray
    feet: np.ndarray
    rest_hips: np.ndarray
    rest_up: np.ndarray
    standing_height: float

    @classmethod
    def of(cls, joints: np.ndarray, rest: np.ndarray) -> Pelvis:
        """From ``joints`` (T, 4, 3) and ``rest`` (4, 3): the :data:`PELVIS_JOINTS` posed at each
        frame and at rest."""
        j = np.asarray(joints, np.float64)
        r = np.asarray(rest, np.float64)
        if j.ndim != 3 or j.shape[1:] != (4, 3) or r.shape != (4, 3):
            raise InputError(f"need joints (T, 4, 3) and rest (4, 3): got {j.shape}, {r.shape}")
        return cls(
            hips=j[:, 0],
            up=j[:, 1] - j[:, 0],
            feet=j[:, 2:4],
            rest_hips=r[0],
            rest_up=r[1] - r[0],
            standing_height=float(r[0, 1] - r[2:4, 1].min()),
        )


@dataclass(frozen=True)
class BandMeasures:
    """A simulated garment's waistband and hem against the body (:func:`band_measures`); each
    None where it does not apply (as each says).

    Attributes
    ----------
    hem_radius_ratio : the hem's mean distance from the waist's axis over the clip's second
        half over the garment's as dressed (:func:`hem_radius_ratio`): above 1 it flared out.
        None without pins or a hem apart from them, or under 2 frames
    waistband_rise_max_mm : the pinned waistband's largest rise or sink along the pelvis
        against frame 0 (:func:`rise_over_hips`). None without pins
    hem_rise_end_mm : the hem's height along the pelvis above the hips (:func:`band_height`)
        over the clip's last ``end_frames``, against the garment's as dressed on the rest pose:
        a hem that rode up and stayed. Only where the body stands all that while
        (:func:`not_standing`), else None (and as for the ratio). A hem hanging settled on a
        standing body reads a little below 0: it sags from its dressed shape
    end_tilt_deg : the pelvis's largest tilt from the vertical over those frames (as the ratio)
    end_hips_height : the hips' least height above the lower foot over those frames, as a share
        of the rest pose's (as the ratio)
    end_feet_m : the feet's widest apart over those frames (metres; as the ratio)
    """

    hem_radius_ratio: float | None
    waistband_rise_max_mm: float | None
    hem_rise_end_mm: float | None
    end_tilt_deg: float | None
    end_hips_height: float | None
    end_feet_m: float | None


def band_measures(
    positions: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    pins: np.ndarray,
    pelvis: Pelvis,
    end_frames: int,
) -> BandMeasures:
    """The :class:`BandMeasures` of ``positions`` (T, V, 3) simulated from the garment as
    dressed, ``vertices`` (V, 3) and ``faces`` (F, 3), pinned at ``pins`` (P,) int, on a body
    whose :class:`Pelvis` has at least T frames; the hem's end over its last ``end_frames``.

    Against the garment as dressed rather than frame 0: a window cut from a capture may start
    bent over or crouched, where the hem hangs far from the waist's vertical axis and high
    along the tilted pelvis (docs/decisions.md, "Hem at end").
    """
    p = np.asarray(positions, np.float64)
    t = len(p)
    hips, up, feet = pelvis.hips[:t], pelvis.up[:t], pelvis.feet[:t]
    hem = hem_indices(vertices, faces)
    waist = flare = rise_end = tilt_end = height_end = feet_end = None
    if len(pins):
        waist = 1e3 * float(np.abs(rise_over_hips(p, pins, hips, up)).max())
    if t >= 2 and len(pins) and not np.isin(hem, pins).all():
        dressed = np.asarray(vertices, np.float64)[None]
        flare = hem_radius_ratio(p, hem, pins, reference=float(hem_radius(dressed, hem, pins)[0]))
        end = slice(max(t - int(end_frames), 0), t)
        tilt_end = float(pelvis_tilt(up[end]).max())
        height = hips[end, 1] - feet[end, :, 1].min(axis=1)
        height_end = float(height.min() / pelvis.standing_height)
        feet_end = float(np.linalg.norm(feet[end, 0] - feet[end, 1], axis=1).max())
        if not_standing(tilt_end, height_end, feet_end) is None:
            rest = band_height(dressed, hem, pelvis.rest_hips[None], pelvis.rest_up[None])[0]
            rise_end = 1e3 * float(band_height(p, hem, hips, up)[end].mean() - rest)
    return BandMeasures(flare, waist, rise_end, tilt_end, height_end, feet_end)


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
