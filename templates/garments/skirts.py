"""Skirts: layered (tiered ruffles, double layer, tango, plain templates) and pleated.

All skirts hang from a waistline around the vertical body axis (see :mod:`.fit`); every
layer is kept outside the body's hanging profile plus a clearance, and every later part
outside the parts built before it (:class:`Stack`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from core.errors import InputError
from core.numeric import smoothstep

from .fit import BodyFit, RadialProfile
from .surface import (
    Folds,
    Part,
    cylinder_points,
    drop_unused,
    grid_faces,
    grid_part,
    grid_size,
    max_folds,
    weld_columns,
)

#: Probe grid used to measure a surface before choosing its resolution.
_PROBE_ROWS, _PROBE_COLS = 40, 1024

RadiusFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


class Stack:
    """Radii already taken by cloth, so that each new part goes outside the earlier ones.

    ``floor(y, theta)`` is the larger of the body's profile and every shell covering height
    ``y`` plus ``gap``. Shells store an upper bound of their radius (folds at full depth).
    """

    def __init__(self, body: RadialProfile, gap: float):
        self.body = body
        self.gap = gap
        self.shells: list[tuple[float, float, RadiusFn]] = []

    def add(self, y_lo: float, y_hi: float, outer: RadiusFn) -> None:
        self.shells.append((y_lo, y_hi, outer))

    def floor(self, y: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Smallest radius free for cloth at heights ``y``, angles ``theta`` (broadcast)."""
        y, theta = np.broadcast_arrays(np.asarray(y, np.float64), np.asarray(theta, np.float64))
        r = self.body(y, theta)
        for y_lo, y_hi, outer in self.shells:
            inside = (y >= y_lo) & (y <= y_hi)
            if inside.any():
                r = np.where(inside, np.maximum(r, outer(y, theta) + self.gap), r)
        return r


@dataclass(frozen=True)
class SkirtConfig:
    """A layered skirt: concentric layers from one waistline, each with its own hem.

    Heights are fractions of the body height; lengths in metres. Layers are listed from the
    innermost (usually the longest) outwards.
    """

    top: float = 0.63
    """Waistline height (0.63: the waist, at Spine1; 0.58: low on the hips)."""
    hems: tuple[float, ...] = (0.30,)
    """Hem height of each layer."""
    flares: tuple[float, ...] = (0.08,)
    """Extra radius (m) of each layer at its hem over the body's hanging profile."""
    folds: tuple[int, ...] = (0,)
    """Folds around each layer's hem (fewer where the resolution cannot show them)."""
    fold_depths: tuple[float, ...] = (0.0,)
    """Radial depth (m) of each layer's folds at the hem; they fade out at the waist."""
    ease: float = 0.004
    """Room (m) between the body profile (with clearance) and the innermost layer."""
    clearance: float = 0.007
    """Least distance (m) from the body's surface."""
    gap: float = 0.004
    """Radial gap (m) between one part and the next one outside it."""
    frill_depth: float = 0.0
    """Length (m) of the gathered frill hanging from each layer's hem; 0: no frills."""
    frill_overlap: float = 0.015
    """How far (m) a frill starts above its layer's hem (sewn on the outside)."""
    frill_flare: float = 0.03
    """How far (m) a frill flares out over its length."""
    frill_folds: int = 110
    """Folds around a frill (high frequency; clamped by the resolution)."""
    frill_fold_depth: float = 0.012
    """Radial depth (m) of a frill's folds at its lower edge."""
    scallops: int = 0
    """Scallops around each frill's lower edge (a lace-like border); 0: straight edge."""
    scallop_depth: float = 0.012
    """Height (m) of a scallop."""
    hem_tilt: float = 0.0
    """Asymmetric hem: how far (m) the outermost layer's hem rises towards ``hem_high_angle``."""
    hem_high_angle: float = 0.0
    """Angle (rad, 0 = front, pi/2 = left) where an asymmetric hem is highest."""
    slit_top: float = 0.0
    """Height of the top of a slit in the outermost layer; 0: no slit."""
    slit_angle: float = 0.0
    """Angle (rad) of the slit."""
    slit_opening: float = 0.05
    """Width (m) the slit stands open at the hem."""
    flounce_depth: float = 0.0
    """Length (m) of a flounce continuing the outermost layer below its hem; 0: none."""
    flounce_flare: float = 0.12
    """How far (m) the flounce flares out."""
    flounce_folds: int = 36
    """Folds around the flounce."""
    flounce_fold_depth: float = 0.04
    """Radial depth (m) of the flounce's folds at its edge."""
    waistband: float = 0.0
    """Height (m) of a waistband over the layers' tops; 0: none."""

    def __post_init__(self) -> None:
        n = len(self.hems)
        if n == 0 or not all(len(t) == n for t in (self.flares, self.folds, self.fold_depths)):
            raise InputError(
                "skirt config: hems, flares, folds and fold_depths need one entry per layer"
            )
        if not all(0.05 < hem < self.top for hem in self.hems):
            raise InputError(
                f"skirt config: hems {self.hems} must lie between 0.05 and top {self.top}"
            )


def build_layered_skirt(cfg: SkirtConfig, res: float, fit: BodyFit, seed: int) -> list[Part]:
    """Parts of a layered skirt: ``layer-1..n`` (inside out), ``frill-1..n``, ``waistband``.

    Parameters
    ----------
    res : target edge length (m)
    fit : the body to fit
    seed : seeds the irregularity of folds
    """
    rng = np.random.default_rng(seed)
    h = fit.shape.height
    y_top = cfg.top * h
    band_top = y_top + 0.3 * cfg.waistband
    lowest = min(cfg.hems) * h - cfg.frill_depth - cfg.flounce_depth - 0.02
    body = fit.profile(band_top, lowest, cfg.clearance, hanging=True)
    stack = Stack(body, cfg.gap)
    parts: list[Part] = []
    n_layers = len(cfg.hems)
    layer_info = []
    for k in range(n_layers):
        outermost = k == n_layers - 1
        hem = cfg.hems[k] * h
        tilt = cfg.hem_tilt if outermost else 0.0
        flounce = cfg.flounce_depth if outermost else 0.0
        base_floor = stack.floor  # shells below this layer only (bound now)
        floor_snapshot = _freeze_floor(stack)

        def hem_y(theta, hem=hem, tilt=tilt):
            return hem + tilt * (0.5 + 0.5 * np.cos(theta - cfg.hem_high_angle)) ** 2

        perim = 2 * np.pi * (float(np.mean(base_floor(hem, _ANGLES))) + cfg.flares[k])
        folds = Folds.make(min(cfg.folds[k], max_folds(perim, res)), rng, twist=rng.normal() * 4)
        fl_folds = Folds.make(
            min(cfg.flounce_folds, max_folds(perim + 2 * np.pi * cfg.flounce_flare, res)),
            rng,
            sharpness=1.6,
        )

        def radius(y, theta, bound=False, k=k, hem_y=hem_y, floor=floor_snapshot,
                   folds=folds, fl_folds=fl_folds, flounce=flounce):  # fmt: skip
            hy = hem_y(theta)
            length = y_top - hy
            s = np.maximum(y_top - y, 0.0)
            x = s / length
            r = floor(y, theta) + cfg.ease + cfg.flares[k] * np.clip(x, 0, 1.5) ** 1.5
            amp = cfg.fold_depths[k] * (0.1 + 0.9 * smoothstep(x))
            r = r + (amp if bound else amp * folds(theta, s))
            if flounce > 0:
                v = np.clip((hy - y) / flounce, 0.0, 1.0)
                r = r + cfg.flounce_flare * v**1.5
                fl_amp = cfg.flounce_fold_depth * v
                r = r + (fl_amp if bound else fl_amp * fl_folds(theta, s))
            return r

        def surface(u, theta, hem_y=hem_y, radius=radius, flounce=flounce):
            y = y_top + u[:, None] * (hem_y(theta) - flounce - y_top)
            return cylinder_points(theta, y, radius(y, theta), fit.axis_z)

        slit = cfg.slit_top > 0 and outermost
        part = _tube(f"layer-{k + 1}", surface, res, slit=(cfg, h) if slit else None)
        parts.append(part)
        y_lo = float(part.vertices[:, 1].min()) - res
        stack.add(y_lo, y_top + res, lambda y, t, radius=radius: radius(y, t, bound=True))
        layer_info.append((hem_y, perim))

    if cfg.frill_depth > 0:
        for k, (hem_y, perim) in enumerate(layer_info):
            parts.append(_frill(cfg, k, hem_y, perim, stack, res, fit, rng))
    if cfg.waistband > 0:
        parts.append(_waistband(cfg.waistband, band_top, stack, res, fit))
    return parts


_ANGLES = np.linspace(0, 2 * np.pi, 256, endpoint=False)


def _freeze_floor(stack: Stack) -> RadiusFn:
    """The stack's floor as it is now (later shells do not change it)."""
    shells = list(stack.shells)
    frozen = Stack(stack.body, stack.gap)
    frozen.shells = shells
    return frozen.floor


def _tube(
    name: str,
    surface: Callable[[np.ndarray, np.ndarray], np.ndarray],
    res: float,
    slit: tuple[SkirtConfig, float] | None = None,
) -> Part:
    """A tube part from ``surface(u (R,), theta (R, C) or (C,)) -> (R, C, 3)``, u in [0, 1].

    With ``slit``, the tube opens from the config's ``slit_top`` down: it is built as a sheet
    whose first and last columns meet above the slit and part below it.
    """
    probe_u = np.linspace(0, 1, _PROBE_ROWS)
    probe_t = np.linspace(0, 2 * np.pi, _PROBE_COLS, endpoint=False)
    rows, cols = grid_size(surface(probe_u, probe_t), res, periodic=True)
    u = np.linspace(0, 1, rows)
    if slit is None:
        theta = np.linspace(0, 2 * np.pi, cols, endpoint=False)
        return grid_part(name, surface(u, theta), periodic=True)
    cfg, h = slit
    top = cfg.slit_top * h
    # Heights of the seam column decide where the slit is open.
    seam = surface(u, np.array([cfg.slit_angle]))[:, 0]
    r_seam = np.hypot(seam[:, 0], seam[:, 2])
    y_seam = seam[:, 1]
    low = y_seam.min()
    opening = cfg.slit_opening * smoothstep((top - y_seam) / max(top - low, 1e-6))
    delta = opening / (2 * np.maximum(r_seam, 0.05))  # half-opening angle per row
    j = np.arange(cols + 1) / cols
    theta = cfg.slit_angle + delta[:, None] + (2 * np.pi - 2 * delta[:, None]) * j[None, :]
    pts = np.stack([surface(u[i : i + 1], theta[i])[0] for i in range(rows)])
    faces = grid_faces(rows, cols + 1, periodic=False)
    faces = weld_columns(rows, cols + 1, faces, delta == 0)
    return drop_unused(Part(name, pts.reshape(-1, 3), faces))


def _frill(
    cfg: SkirtConfig,
    k: int,
    hem_y: Callable[[np.ndarray], np.ndarray],
    perim: float,
    stack: Stack,
    res: float,
    fit: BodyFit,
    rng: np.random.Generator,
) -> Part:
    """A gathered frill sewn on the outside of layer ``k``'s hem, with a scalloped edge."""
    perim = perim + 2 * np.pi * (cfg.fold_depths[k] + cfg.frill_flare)
    folds = Folds.make(min(cfg.frill_folds, max_folds(perim, res)), rng, sharpness=1.5)
    scallops = min(cfg.scallops, int(perim / (4 * res)))
    floor = _freeze_floor(stack)

    def edges(theta):
        top = hem_y(theta) + cfg.frill_overlap
        bottom = hem_y(theta) - cfg.frill_depth
        if scallops:
            bottom = bottom + cfg.scallop_depth * (
                1 - np.sqrt(np.abs(np.sin(0.5 * scallops * theta)))
            )
        return top, bottom

    def radius(y, theta, bound=False):
        top, bottom = edges(theta)
        v = np.clip((top - y) / (top - bottom), 0.0, 1.0)
        # Below the hem the layer is gone: keep hanging from its hem, and outside anything lower.
        hang = np.maximum(y, hem_y(theta) + 0.5 * cfg.frill_overlap)
        r = np.maximum(floor(y, theta), floor(hang, theta)) + cfg.frill_flare * v**1.2
        amp = cfg.frill_fold_depth * (0.35 + 0.65 * v)
        return r + (amp if bound else amp * folds(theta, top - y))

    def surface(u, theta):
        top, bottom = edges(theta)
        y = top + u[:, None] * (bottom - top)
        return cylinder_points(theta, y, radius(y, theta), fit.axis_z)

    part = _tube(f"frill-{k + 1}", surface, res)
    y = part.vertices[:, 1]
    stack.add(float(y.min()) - res, float(y.max()) + res, lambda y, t: radius(y, t, bound=True))
    return part


def _waistband(height: float, top: float, stack: Stack, res: float, fit: BodyFit) -> Part:
    """A straight band over the tops of everything below: the same cross-section top to bottom."""
    rows = max(2, math.ceil(height / res) + 1)
    ys = np.linspace(top, top - height, rows)
    probe = np.linspace(0, 2 * np.pi, _PROBE_COLS, endpoint=False)
    ring = stack.floor(ys[:, None], probe[None, :]).max(axis=0)
    perim = 2 * np.pi * float(ring.mean())
    cols = max(8, math.ceil(perim / res))
    theta = np.linspace(0, 2 * np.pi, cols, endpoint=False)
    r = stack.floor(ys[:, None], theta[None, :]).max(axis=0)
    # Include the probe's maxima between columns (a band is a prism, no folds).
    r = np.maximum(r, np.interp(theta, probe, ring, period=2 * np.pi))
    pts = cylinder_points(theta[None, :], ys[:, None], r[None, :], fit.axis_z)
    part = grid_part("waistband", pts, periodic=True)
    r_max = r.copy()
    stack.add(
        top - height - res,
        top + res,
        lambda y, t: np.interp(np.mod(t, 2 * np.pi), theta, r_max, period=2 * np.pi) + 0 * y,
    )
    return part


# --------------------------------------------------------------------------------------------
# Pleated skirts


@dataclass(frozen=True)
class PleatConfig:
    """A pleated skirt: the cloth folded into knife or (inverted) box pleats all around.

    Heights are fractions of the body height; lengths in metres.
    """

    top: float = 0.585
    """Waistline height (low on the hips by default)."""
    hem: float = 0.42
    """Hem height (a short skirt: mid-thigh)."""
    pleats: int = 18
    """Number of pleats around."""
    kind: str = "knife"
    """``"knife"`` (all folds facing one way) or ``"box"`` (pairs of folds meeting)."""
    fold_under: float = 0.55
    """Depth of each fold as a fraction of the visible pleat width."""
    gap_top: float = 0.002
    """Radial spacing (m) of the folded layers at the waist (pressed flat)."""
    gap_hem: float = 0.012
    """Radial spacing (m) of the folded layers at the hem (the pleats open up)."""
    flare: float = 0.07
    """Extra radius (m) at the hem over the body's hanging profile."""
    clearance: float = 0.007
    """Least distance (m) from the body's surface."""
    waistband: float = 0.035
    """Height (m) of the waistband; 0: none."""

    def __post_init__(self) -> None:
        if self.kind not in ("knife", "box"):
            raise InputError(f"pleat kind {self.kind!r}: use 'knife' or 'box'")
        if not 0.1 <= self.fold_under <= 0.9:
            raise InputError(f"pleat fold_under {self.fold_under} outside [0.1, 0.9]")
        if not (0.05 < self.hem < self.top) or self.pleats < 4:
            raise InputError("pleat config: need 0.05 < hem < top and at least 4 pleats")


def pleat_pattern(
    kind: str, fold_under: float, samples: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cross-section of one pleat, sampled along the cloth.

    The pleat spans angle units [0, 1) (one pleat's share of the circle); the cloth runs
    forward on the outside, folds under and back, and forward again on the inside.

    Parameters
    ----------
    kind : "knife" or "box"
    fold_under : fold depth as a fraction of the pleat width
    samples : number of samples along the cloth

    Returns
    -------
    pos : (S,) float64
        Position along the circle in pleat units (may leave [0, 1) under the folds).
    level : (S,) float64
        Layer: 0 inside, 1 middle, 2 outside (times the layer spacing gives the radius).
    turn : (S,) float64
        Sideways bulge of the folds, in units of the layer spacing (added to ``pos`` after
        scaling by spacing / radius).
    """
    b = fold_under
    # Segments: (start pos, end pos, start level, end level, turn direction or 0).
    if kind == "knife":
        # Outer face rises from the inside to the outside, folds back (middle), folds forward
        # (inside) and becomes the next pleat's face.
        rise = max(1 - b - 0.12, 0.05)
        segs = [
            (0.0, rise, 0.0, 2.0, 0),
            (rise, 1.0, 2.0, 2.0, 0),
            (1.0, 1.0, 2.0, 1.0, +1),
            (1.0, 1.0 - b, 1.0, 1.0, 0),
            (1.0 - b, 1.0 - b, 1.0, 0.0, -1),
            (1.0 - b, 1.0, 0.0, 0.0, 0),
        ]
    else:
        # Inverted box pleat: two folds meet at the pleat's end, a little gap between them.
        c = 0.05
        h = 0.5 * b
        segs = [
            (c, 1.0 - c, 2.0, 2.0, 0),
            (1.0 - c, 1.0 - c, 2.0, 1.0, +1),
            (1.0 - c, 1.0 - h, 1.0, 1.0, 0),
            (1.0 - h, 1.0 - h, 1.0, 0.0, -1),
            (1.0 - h, 1.0 + h, 0.0, 0.0, 0),
            (1.0 + h, 1.0 + h, 0.0, 1.0, +1),
            (1.0 + h, 1.0 + c, 1.0, 1.0, 0),
            (1.0 + c, 1.0 + c, 1.0, 2.0, -1),
        ]
    turn_len = np.pi / 2 * 0.05  # a fold's length in pleat units (nominal)
    lengths = np.array([abs(e - s) if d == 0 else turn_len for s, e, _, _, d in segs])
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    t = np.linspace(0, cum[-1], samples, endpoint=False)
    seg = np.clip(np.searchsorted(cum, t, side="right") - 1, 0, len(segs) - 1)
    w = (t - cum[seg]) / lengths[seg]
    s0, s1, l0, l1, d = (np.array([sg[i] for sg in segs], np.float64) for i in range(5))
    pos = s0[seg] + w * (s1[seg] - s0[seg])
    sm = smoothstep(w)
    level = l0[seg] + np.where(d[seg] == 0, sm, w) * (l1[seg] - l0[seg])
    bulge = 0.5 if kind == "knife" else 0.15  # box folds meet: keep their bulges apart
    turn = np.where(d[seg] != 0, d[seg] * bulge * np.sin(np.pi * w), 0.0)
    if kind == "box":
        pos = pos - c  # start the pattern at the panel's start
    return pos, level, turn


def build_pleated_skirt(cfg: PleatConfig, res: float, fit: BodyFit, seed: int) -> list[Part]:
    """Parts of a pleated skirt: ``pleats`` (one folded sheet around) and ``waistband``.

    The folded-under layers face the body (the cloth turns over at every fold); the outside
    faces point away from it. ``seed`` is unused: pleats are regular.
    """
    del seed
    h = fit.shape.height
    y_top, y_hem = cfg.top * h, cfg.hem * h
    band_top = y_top + 0.3 * cfg.waistband
    body = fit.profile(band_top, y_hem - 0.02, cfg.clearance, hanging=True)
    stack = Stack(body, 0.004)
    length = y_top - y_hem
    unit = 2 * np.pi / cfg.pleats

    def gap(y):
        return cfg.gap_top + (cfg.gap_hem - cfg.gap_top) * smoothstep((y_top - y) / length)

    def base(y, theta):
        x = np.clip((y_top - y) / length, 0, 1)
        return body(y, theta) + cfg.flare * x**1.3

    # Samples along the cloth: enough for the longest ring (hem, with the folds under).
    hem_r = float(np.mean(base(y_hem, _ANGLES)))
    cloth_per_pleat = (1 + 2 * cfg.fold_under + 0.2) * unit * hem_r
    per_pleat = max(6, math.ceil(cloth_per_pleat / res))
    rows = max(2, math.ceil(length / res) + 1)
    pos, level, turn = pleat_pattern(cfg.kind, cfg.fold_under, per_pleat)
    k = np.arange(cfg.pleats)
    ys = np.linspace(y_top, y_hem, rows)[:, None]
    g = gap(ys)
    theta0 = (k[:, None] + pos[None, :]).reshape(-1) * unit
    r0 = base(ys, theta0[None, :])
    theta = theta0[None, :] + np.tile(turn, cfg.pleats)[None, :] * g / r0
    r = base(ys, theta) + np.tile(level, cfg.pleats)[None, :] * g
    pts = cylinder_points(theta, np.broadcast_to(ys, theta.shape), r, fit.axis_z)
    parts = [grid_part("pleats", pts, periodic=True)]
    stack.add(y_hem - res, band_top + res, lambda y, t: base(y, t) + 2 * gap(y) + 0.002)
    if cfg.waistband > 0:
        parts.append(_waistband(cfg.waistband, band_top, stack, res, fit))
    return parts
