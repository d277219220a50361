"""Dresses: a fitted bodice and a flared skirt in one piece, with straps, a sash and a bow."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.errors import InputError

from .fit import BodyFit, flared_tube
from .skirts import Stack, _tube, _waistband
from .surface import (
    Part,
    cylinder_points,
    grid_part,
    orient_away,
    ribbon_points,
)


@dataclass(frozen=True)
class DressConfig:
    """A dress. Heights are fractions of the body height; lengths in metres."""

    top: float = 0.75
    """Height of the bodice's top edge at the sides (below the armpits)."""
    neckline_dip: float = 0.03
    """How far (m) the top edge dips at the front centre."""
    waist: float = 0.625
    """Waistline height, where the bodice meets the skirt."""
    hem: float = 0.25
    """Hem height (0.25: mid-calf)."""
    ease: float = 0.003
    """Room (m) between the body profile (with clearance) and the dress."""
    clearance: float = 0.007
    """Least distance (m) from the body's surface."""
    flare: float = 0.16
    """Extra radius (m) of the skirt at the hem."""
    folds: int = 16
    """Folds around the skirt's hem."""
    fold_depth: float = 0.045
    """Radial depth (m) of the skirt's folds at the hem; none at the waist."""
    gap: float = 0.004
    """Radial gap (m) between a part and the one under it."""
    straps: float = 0.02
    """Shoulder strap width (m); 0: strapless."""
    strap_x: float = 0.25
    """Strap distance from the centre line as a fraction of the shoulder width."""
    sash: float = 0.05
    """Height (m) of a sash around the waist; 0: none."""
    bow: float = 0.075
    """Span (m) of one bow loop, out from the knot; 0: no bow (needs a sash)."""
    bow_angle: float = 0.0
    """Where the bow sits around the waist (rad, 0 = front, pi = back)."""

    def __post_init__(self) -> None:
        if not (0.05 < self.hem < self.waist < self.top < 0.8):
            raise InputError("dress config: need 0.05 < hem < waist < top < 0.8")
        if self.bow > 0 and self.sash <= 0:
            raise InputError("dress config: a bow needs a sash")


def build_dress(cfg: DressConfig, res: float, fit: BodyFit, seed: int) -> list[Part]:
    """Parts of a dress: ``dress`` (bodice and skirt), ``sash``, ``straps``, ``bow``.

    Parameters
    ----------
    res : target edge length (m)
    fit : the body to fit
    seed : seeds the irregularity of the skirt's folds
    """
    rng = np.random.default_rng(seed)
    h = fit.shape.height
    y_top, y_waist, y_hem = cfg.top * h, cfg.waist * h, cfg.hem * h
    local, body, radius = flared_tube(
        fit, y_top, y_waist, y_hem, cfg.clearance, cfg.ease, cfg.flare, cfg.fold_depth,
        cfg.folds, res, rng,
    )  # fmt: skip
    top_edge = _top_edge(cfg, fit, local, y_top, y_waist)

    def surface(u, theta):
        y = top_edge(theta) + u[:, None] * (y_hem - top_edge(theta))
        return cylinder_points(theta, y, radius(y, theta), fit.axis_z)

    dress = _tube("dress", surface, res)
    parts = [dress]
    stack = Stack(body, cfg.gap)
    stack.add(y_hem - res, y_top + res, lambda y, t: radius(y, t, bound=True))

    def outside_dress(p: np.ndarray, below: np.ndarray) -> np.ndarray:
        """Push points (N, 3) radially out of the dress where ``below`` (N,) bool."""
        rel = p - [0.0, 0.0, fit.axis_z]
        theta = np.arctan2(rel[:, 0], rel[:, 2])
        r = np.hypot(rel[:, 0], rel[:, 2])
        need = stack.floor(p[:, 1], theta)
        r_new = np.where(below, np.maximum(r, need), r)
        return cylinder_points(theta, p[:, 1], r_new, fit.axis_z)

    if cfg.straps > 0:
        parts.append(_straps(cfg, fit, res, top_edge, outside_dress))
    if cfg.sash > 0:
        sash = _waistband(cfg.sash, y_waist + 0.5 * cfg.sash, stack, res, fit)
        parts.append(Part("sash", sash.vertices, sash.faces))
        if cfg.bow > 0:
            parts.append(_bow(cfg, fit, res, y_waist, sash, outside_dress))
    return parts


def _top_edge(cfg: DressConfig, fit: BodyFit, local, y_top: float, y_waist: float):
    """The bodice's top edge ``y(theta)``: a neckline dip at the front, and armholes cut low
    enough under the arms that the arms stay clear of the cloth (heavy arms reach the torso).
    """
    n = 360
    thetas = np.linspace(0, 2 * np.pi, n, endpoint=False)
    edge = y_top - cfg.neckline_dip * (0.5 + 0.5 * np.cos(thetas)) ** 4
    arm = fit.vertices[fit.arms]
    rel = arm - [0.0, 0.0, fit.axis_z]
    th = np.arctan2(rel[:, 0], rel[:, 2])
    r = np.hypot(rel[:, 0], rel[:, 2])
    margin = cfg.ease + cfg.gap + 0.015
    close = (r < local(arm[:, 1], th) + margin) & (arm[:, 1] > y_waist)
    if close.any():
        # Lowest close arm point within a window of angles around each sample.
        window = 0.25
        d = np.abs(np.angle(np.exp(1j * (thetas[:, None] - th[close][None, :]))))
        ys = np.where(d < window, arm[close, 1][None, :], np.inf).min(axis=1)
        limit = ys - 0.015
        edge = np.minimum(edge, limit)
        # Smooth the armhole curve without ever rising above the limit.
        for _ in range(400):
            smooth = 0.25 * np.roll(edge, 1) + 0.5 * edge + 0.25 * np.roll(edge, -1)
            edge = np.minimum(smooth, np.minimum(limit, y_top))
    edge = np.maximum(edge, y_waist + 0.05)

    def top_edge(theta):
        return np.interp(np.mod(theta, 2 * np.pi), thetas, edge, period=2 * np.pi)

    return top_edge


def _straps(cfg: DressConfig, fit: BodyFit, res: float, top_edge, outside_dress) -> Part:
    """Two ribbons from the bodice's front edge over the shoulders to its back edge."""
    import open3d as o3d

    h = fit.shape.height
    # The whole closed body: the strap's plane passes beside the neck and inside the arms.
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(fit.vertices.astype(np.float32)),
        o3d.core.Tensor(fit.faces.astype(np.uint32)),
    )
    clearance = cfg.clearance + cfg.gap
    phi = np.linspace(-1.3, np.pi + 1.3, 600)
    u = np.stack([np.zeros_like(phi), np.sin(phi), np.cos(phi)], axis=1)
    n_across = max(2, math.ceil(cfg.straps / res) + 1)
    vs, fs, off = [], [], 0
    for sx in (1.0, -1.0):
        xs = sx * cfg.strap_x * fit.shape.shoulder_width
        centre = np.array([xs, 0.775 * h, fit.axis_z])
        reach = np.zeros(len(phi))
        for dx in np.linspace(-0.5, 0.5, 5) * cfg.straps * 1.2:
            origin = centre + [dx, 0.0, 0.0] + 0.8 * u
            rays = np.concatenate([origin, -u], axis=1).astype(np.float32)
            t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
            reach = np.maximum(reach, np.where(np.isfinite(t), 0.8 - t, 0.0))
        path = centre + u * (reach + clearance)[:, None]
        theta = np.arctan2(path[:, 0], path[:, 2] - fit.axis_z)
        keep = path[:, 1] >= top_edge(theta) - 0.03
        keep &= reach > 0
        # The run of kept samples that goes over the shoulder (contains phi = pi / 2).
        mid = int(np.argmin(np.abs(phi - np.pi / 2)))
        lo, hi = mid, mid
        while lo > 0 and keep[lo - 1]:
            lo -= 1
        while hi < len(phi) - 1 and keep[hi + 1]:
            hi += 1
        path = path[lo : hi + 1]
        seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        n_along = max(3, math.ceil(s[-1] / res) + 1)
        si = np.linspace(0, s[-1], n_along)
        centre_line = np.stack([np.interp(si, s, path[:, i]) for i in range(3)], axis=1)
        across = np.tile([1.0, 0.0, 0.0], (n_along, 1))
        pts = ribbon_points(centre_line, across, np.full(n_along, cfg.straps), n_across)
        flat = pts.reshape(-1, 3)
        rel = flat - [0.0, 0.0, fit.axis_z]
        th = np.arctan2(rel[:, 0], rel[:, 2])
        flat = outside_dress(flat, flat[:, 1] < top_edge(th) + 0.01)
        part = orient_away(grid_part("straps", flat.reshape(pts.shape), periodic=False), centre)
        vs.append(part.vertices)
        fs.append(part.faces + off)
        off += len(part.vertices)
    return Part("straps", np.concatenate(vs), np.concatenate(fs))


def _bow(
    cfg: DressConfig, fit: BodyFit, res: float, y_waist: float, sash: Part, outside_dress
) -> Part:
    """A bow on the sash: two loops, a knot and two tails with notched ends."""
    rel = sash.vertices - [0.0, 0.0, fit.axis_z]
    theta_v = np.arctan2(rel[:, 0], rel[:, 2])
    near = np.abs(np.angle(np.exp(1j * (theta_v - cfg.bow_angle)))) < 0.05
    r_front = float(np.hypot(rel[near, 0], rel[near, 2]).max())
    out = np.array([np.sin(cfg.bow_angle), 0.0, np.cos(cfg.bow_angle)])
    side = np.array([np.cos(cfg.bow_angle), 0.0, -np.sin(cfg.bow_angle)])
    up = np.array([0.0, 1.0, 0.0])
    origin = np.array([0.0, y_waist, fit.axis_z]) + (r_front + cfg.gap) * out

    def world(x, y, z):
        return origin + x[..., None] * side + y[..., None] * up + z[..., None] * out

    span = cfg.bow
    w_knot, w_end = 0.2 * span, 0.6 * span
    thick = 0.16 * span  # half-thickness of a loop
    knot_y, knot_z = 0.5 * w_knot + 0.006, 0.6 * thick + 0.004
    zc = knot_z + 0.003
    pieces: list[Part] = []
    # Loops: flattened rings in the side/out plane, the ribbon's width along up.
    n_ring = max(12, math.ceil(2 * np.pi * 0.5 * span / res))
    n_w = max(2, math.ceil(w_end / res) + 1)
    phi = np.linspace(0, 2 * np.pi, n_ring, endpoint=False)
    s = np.linspace(-0.5, 0.5, n_w)
    for sx in (1.0, -1.0):
        a = 0.5 - 0.5 * np.cos(phi)
        x = sx * (0.003 + span * a)
        z = zc + thick * np.sin(phi) * sx
        width = w_knot + (w_end - w_knot) * a
        yy = 0.25 * np.abs(x)[None, :] + width[None, :] * s[:, None]  # rows across the width
        pts = world(np.broadcast_to(x, yy.shape), yy, np.broadcast_to(z, yy.shape))
        part = grid_part("bow", pts, periodic=True)
        pieces.append(
            orient_away(
                part, world(np.array(sx * span / 2), np.array(0.25 * span / 2), np.array(zc))
            )
        )
    # Knot: a short band around the loops' pinch, in the up/out plane.
    n_k = max(8, math.ceil(2 * np.pi * knot_y / res))
    psi = np.linspace(0, 2 * np.pi, n_k, endpoint=False)
    kx = np.linspace(-0.5, 0.5, max(2, math.ceil(w_knot / res) + 1)) * 0.9 * w_knot
    ky, kz = knot_y * np.cos(psi), zc + knot_z * np.sin(psi)
    pts = world(
        np.broadcast_to(kx[:, None], (len(kx), n_k)),
        np.broadcast_to(ky, (len(kx), n_k)),
        np.broadcast_to(kz, (len(kx), n_k)),
    )
    pieces.append(
        orient_away(
            grid_part("bow", pts, periodic=True), world(np.array(0.0), np.array(0.0), np.array(zc))
        )
    )
    # Tails: ribbons hanging down and out from under the knot, ends cut in a V.
    tail_len, tail_w = 2.4 * span, 0.35 * span
    n_along = max(3, math.ceil(tail_len / res) + 1)
    n_across = max(2, math.ceil(tail_w / res) + 1)
    v = np.linspace(0, 1, n_along)[:, None]
    c = np.linspace(-0.5, 0.5, n_across)[None, :]
    for sx in (1.0, -1.0):
        length = tail_len * (1 - 0.12 * (1 - 2 * np.abs(c)))  # the V notch
        yy = -knot_y - 0.004 - v * length
        xx = sx * (0.004 + 0.5 * tail_w + 0.3 * v * length) + c * tail_w * (1 - 0.2 * v)
        zz = zc + 0.004 * np.sin(6 * v) + 0 * c
        pts = world(xx, yy, np.broadcast_to(zz, xx.shape)).reshape(-1, 3)
        pts = outside_dress(pts, np.ones(len(pts), bool))
        part = grid_part("bow", pts.reshape(n_along, n_across, 3), periodic=False)
        pieces.append(orient_away(part, np.array([0.0, y_waist, fit.axis_z])))
    vs, fs, off = [], [], 0
    for p in pieces:
        vs.append(p.vertices)
        fs.append(p.faces + off)
        off += len(p.vertices)
    return Part("bow", np.concatenate(vs), np.concatenate(fs))
