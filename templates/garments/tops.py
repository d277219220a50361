"""Single-layer tops and dresses with the openings of real garments: necklines, armholes,
straps and sleeves, all sewn into one piece of cloth.

A garment is one connected open surface, the way a single-layer garment exported from a
pattern-making tool looks once its seams are welded:

* the body of the garment is a grid around the vertical axis (columns around, rows down) from
  a shaped top edge ``T(theta)`` (front and back necklines, strap plateaus, armhole curves) to
  the hem, fitted to the mannequin like the dress of :mod:`.dress`;
* each shoulder strap is a ribbon over the shoulder whose first and last rows *are* the
  bodice's top-row vertices under the strap, front and back: the straps split the top edge
  into a neckline and two armholes;
* a sleeve, when asked for, is lofted from the armhole loop itself to a cuff around the arm.

Boundary loops: the hem, the neckline and two armholes (or two cuffs): four in all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.body.shape import mannequin_skeleton
from core.errors import InputError
from core.proxy.topology import boundary_loops

from .fit import BodyFit, flared_tube
from .surface import Part, cylinder_points, grid_faces, grid_size

#: Probe grid used to measure the surface before choosing its resolution.
_PROBE_ROWS, _PROBE_COLS = 40, 1024
#: Angular samples of the top edge before it is read at the grid's columns.
_EDGE_SAMPLES = 720
#: Shoulder arc: ray directions (radians from the front, in a plane x = const) and the distance
#: rays start from.
_ARC_PHI = np.linspace(-1.3, np.pi + 1.3, 600)
_ARC_START = 0.8
#: Arm vertices within this distance (m) along the arm decide the sleeve's least radius.
_ARM_WINDOW = 0.02
#: Vertical space (m) kept between the armhole and the arm points next to the torso.
_ARMPIT_MARGIN = 0.015


@dataclass(frozen=True)
class TopConfig:
    """A single-layer top or dress. Heights are fractions of the body height; lengths in m."""

    hem: float = 0.55
    """Hem height (0.55: the hips, a top; 0.28: mid-calf, a dress)."""
    waist: float = 0.625
    """Where the fitted bodice gives way to cloth hanging from the hips."""
    shoulder: float = 0.77
    """Height where the straps leave the front and back panels."""
    neckline_front: float = 0.09
    """Depth (m) of the front neckline below the strap height, at the centre."""
    neckline_back: float = 0.05
    """Depth (m) of the back neckline."""
    strap_x: float = 0.3
    """Distance of a strap's centre from the centre line, as a fraction of the shoulder width."""
    strap_width: float = 0.05
    """Strap width (m); at least two grid columns whatever the resolution."""
    armhole: float = 0.72
    """Lowest point of an armhole (lowered further where the arms come close to the torso)."""
    sleeve: float = 0.0
    """Sleeve length (m) from the shoulder joint along the arm; 0: sleeveless."""
    sleeve_ease: float = 0.02
    """Room (m) between the arm and the sleeve's cuff."""
    ease: float = 0.006
    """Room (m) between the body profile (with clearance) and the cloth."""
    clearance: float = 0.007
    """Least distance (m) from the body's surface."""
    flare: float = 0.03
    """Extra radius (m) at the hem."""
    folds: int = 0
    """Folds around the hem (fewer where the resolution cannot show them)."""
    fold_depth: float = 0.0
    """Radial depth (m) of the folds at the hem; none at the waist."""

    def __post_init__(self) -> None:
        if not (0.05 < self.hem < self.waist < self.armhole < self.shoulder < 0.8):
            raise InputError("top config: need 0.05 < hem < waist < armhole < shoulder < 0.8")
        if self.strap_width <= 0 or not 0.05 <= self.strap_x <= 0.5:
            raise InputError("top config: need strap_width > 0 and strap_x in [0.05, 0.5]")
        if self.sleeve < 0:
            raise InputError("top config: sleeve length must be >= 0")


def build_top(cfg: TopConfig, res: float, fit: BodyFit, seed: int) -> list[Part]:
    """One part, the whole garment in one piece (bodice or skirt, straps, sleeves).

    Parameters
    ----------
    res : target edge length (m)
    fit : the body to fit
    seed : seeds the irregularity of the folds

    Returns ``[Part]`` named ``"dress"`` when the hem is below the knees, else ``"top"``.
    """
    rng = np.random.default_rng(seed)
    h = fit.shape.height
    y_s, y_waist, y_hem = cfg.shoulder * h, cfg.waist * h, cfg.hem * h
    local, _, radius = flared_tube(
        fit, y_s, y_waist, y_hem, cfg.clearance, cfg.ease, cfg.flare, cfg.fold_depth,
        cfg.folds, res, rng,
    )  # fmt: skip

    # Columns first (an even number, so that every column has its mirror image front to
    # back), then the strap bands on whole columns, then the top edge.
    probe_t = np.linspace(0, 2 * np.pi, _PROBE_COLS, endpoint=False)
    probe_u = np.linspace(0, 1, _PROBE_ROWS)
    probe_y = y_s + probe_u[:, None] * (y_hem - y_s) + 0 * probe_t
    probe = cylinder_points(probe_t, probe_y, radius(probe_y, probe_t), fit.axis_z)
    rows, cols = grid_size(probe, res, periodic=True)
    cols += cols % 2
    step = 2 * np.pi / cols
    theta = step * np.arange(cols)
    band_c, band_w = _strap_band(cfg, fit, local, y_s, step)
    top = _top_edge(cfg, fit, local, band_c, band_w, y_s, y_waist)(theta)
    u = np.linspace(0, 1, rows)
    y = top[None, :] + u[:, None] * (y_hem - top[None, :])
    grid = cylinder_points(theta[None, :], y, radius(y, theta[None, :]), fit.axis_z)
    vertices = grid.reshape(-1, 3)
    faces = grid_faces(rows, cols, periodic=True)

    # Straps: top-row vertices (row 0, index = column) under each band, front and back.
    vertices, faces = _add_straps(cfg, fit, res, vertices, faces, theta, band_c, band_w, y_s)
    if cfg.sleeve > 0:
        for side in (1.0, -1.0):
            vertices, faces = _add_sleeve(cfg, fit, res, vertices, faces, side)
    # Heavy arms reach the torso's cloth under the armholes: keep the clearance there too.
    vertices = _push_out(vertices, _body_scene(fit), cfg.clearance)
    name = "dress" if cfg.hem < 0.45 else "top"
    return [Part(name, vertices, faces)]


def _strap_band(cfg: TopConfig, fit: BodyFit, local, y_s: float, step: float):
    """Centre angle (rad, front left) and half-width of the strap band, snapped to columns.

    The centre lies half-way between two columns and the half-width covers at least those two,
    so the band holds the same whole columns front and back (mirror images).
    """
    xs = cfg.strap_x * fit.shape.shoulder_width
    theta = 0.5
    for _ in range(20):  # x = r(theta) sin(theta), solved by fixed point
        r = float(local(np.array(y_s), np.array(theta)))
        theta = math.asin(min(xs / r, 0.99))
    centre = (round(theta / step - 0.5) + 0.5) * step
    r = float(local(np.array(y_s), np.array(centre)))
    half = max(0.5 * cfg.strap_width / r, 0.51 * step)
    return centre, half


def _top_edge(cfg: TopConfig, fit: BodyFit, local, centre, half, y_s, y_waist):
    """The top edge ``y(theta)``: necklines front and back, strap plateaus at ``y_s``, armholes
    down to ``cfg.armhole`` (lower where the arms come close to the torso)."""
    h = fit.shape.height
    t = np.linspace(0, 2 * np.pi, _EDGE_SAMPLES, endpoint=False)
    a = np.abs(np.angle(np.exp(1j * t)))  # 0 front .. pi back, mirrored left/right
    inner, outer = centre - half, centre + half
    back_outer, back_inner = np.pi - outer, np.pi - inner
    edge = np.full(len(t), y_s)
    front = a < inner
    x = a[front] / inner
    edge[front] = y_s - cfg.neckline_front * 0.5 * (1 + np.cos(np.pi * x))
    back = a > back_inner
    x = (np.pi - a[back]) / (np.pi - back_inner)
    edge[back] = y_s - cfg.neckline_back * 0.5 * (1 + np.cos(np.pi * x))
    arm = (a > outer) & (a < back_outer)
    x = (a[arm] - outer) / (back_outer - outer)
    y_a = cfg.armhole * h
    edge[arm] = y_s - (y_s - y_a) * 0.5 * (1 - np.cos(2 * np.pi * x))
    # Arms next to the torso (A-pose): keep the armhole below them, smoothly.
    pts = fit.vertices[fit.arms]
    rel = pts - [0.0, 0.0, fit.axis_z]
    th = np.arctan2(rel[:, 0], rel[:, 2])
    r = np.hypot(rel[:, 0], rel[:, 2])
    close = (r < local(pts[:, 1], th) + cfg.ease + _ARMPIT_MARGIN) & (pts[:, 1] > y_waist)
    if close.any():
        d = np.abs(np.angle(np.exp(1j * (t[:, None] - th[close][None, :]))))
        limit = np.where(d < 0.25, pts[close, 1][None, :], np.inf).min(axis=1) - _ARMPIT_MARGIN
        design = edge.copy()
        edge = np.where(arm, np.minimum(edge, limit), edge)
        for _ in range(300):
            smooth = 0.25 * np.roll(edge, 1) + 0.5 * edge + 0.25 * np.roll(edge, -1)
            edge = np.where(arm, np.minimum(smooth, np.minimum(limit, design)), edge)
    edge = np.maximum(edge, y_waist + 0.05)

    def top_edge(theta: np.ndarray) -> np.ndarray:
        theta = np.asarray(theta, np.float64)
        y = np.interp(np.mod(theta, 2 * np.pi), t, edge, period=2 * np.pi)
        aa = np.abs(np.angle(np.exp(1j * theta)))
        on_strap = (np.abs(aa - centre) <= half) | (np.abs(aa - (np.pi - centre)) <= half)
        return np.where(on_strap, y_s, y)

    return top_edge


def _body_scene(fit: BodyFit, head: bool = True):
    """An Open3D ray-casting scene of the closed body; without the neck and head when ``head``
    is False (a strap's arc must ride the shoulder, not climb the side of the head)."""
    import open3d as o3d

    faces = fit.faces if head else fit.faces[(fit.kept | fit.arms)[fit.faces].all(axis=1)]
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(fit.vertices.astype(np.float32)),
        o3d.core.Tensor(faces.astype(np.uint32)),
    )
    return scene


def _push_out(points: np.ndarray, scene, distance: float) -> np.ndarray:
    """Move points (N, 3) closer to the body than ``distance`` (or inside it) out to
    ``distance`` from its surface, away from their closest body point."""
    import open3d as o3d

    p = np.asarray(points, np.float64).copy()
    q = o3d.core.Tensor(p.astype(np.float32))
    signed = scene.compute_signed_distance(q).numpy().astype(np.float64)
    near = signed < distance
    if near.any():
        closest = scene.compute_closest_points(q)["points"].numpy().astype(np.float64)[near]
        out = (p[near] - closest) * np.sign(signed[near])[:, None]
        out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)
        p[near] = closest + distance * out
    return p


def _add_straps(cfg, fit, res, vertices, faces, theta, centre, half, y_s):
    """Ribbons over both shoulders, sharing their end rows with the bodice's top row."""
    import open3d as o3d

    shoulders, scene = _body_scene(fit, head=False), _body_scene(fit)
    h = fit.shape.height
    lift = cfg.clearance + cfg.ease
    u = np.stack([np.zeros_like(_ARC_PHI), np.sin(_ARC_PHI), np.cos(_ARC_PHI)], axis=1)
    aa = np.abs(np.angle(np.exp(1j * theta)))
    vs, fs = [vertices], [faces]
    count = len(vertices)
    for side in (1.0, -1.0):
        sided = np.sign(np.sin(theta)) == side
        front = np.flatnonzero(sided & (np.abs(aa - centre) <= half))
        back = np.flatnonzero(sided & (np.abs(aa - (np.pi - centre)) <= half))
        front = front[np.argsort(vertices[front, 0])]
        back = back[np.argsort(vertices[back, 0])]
        if len(front) != len(back) or len(front) < 2:
            raise InputError("top: strap columns front and back do not match")
        paths = []
        for p_i, q_i in zip(front, back):
            p, q = vertices[p_i], vertices[q_i]
            xc = 0.5 * (p[0] + q[0])
            centre_pt = np.array([xc, 0.775 * h, fit.axis_z])
            reach = np.zeros(len(_ARC_PHI))
            for dx in (-0.5 * res, 0.0, 0.5 * res):
                origin = centre_pt + [dx, 0.0, 0.0] + _ARC_START * u
                rays = np.concatenate([origin, -u], axis=1).astype(np.float32)
                t_hit = shoulders.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(float)
                reach = np.maximum(reach, np.where(np.isfinite(t_hit), _ARC_START - t_hit, 0.0))
            arc = centre_pt + u * (reach + lift)[:, None]
            above = (arc[:, 1] > y_s + 0.25 * res) & (reach > 0)
            mid = int(np.argmin(np.abs(_ARC_PHI - np.pi / 2)))
            lo, hi = mid, mid
            while lo > 0 and above[lo - 1]:
                lo -= 1
            while hi < len(_ARC_PHI) - 1 and above[hi + 1]:
                hi += 1
            path = np.concatenate([p[None], arc[lo : hi + 1], q[None]])
            seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
            s = np.concatenate([[0.0], np.cumsum(seg)])
            path[:, 0] = p[0] + (q[0] - p[0]) * s / s[-1]
            paths.append((path, s))
        n_along = max(3, math.ceil(max(s[-1] for _, s in paths) / res) + 1)
        ribbon = np.empty((n_along, len(front), 3))
        for k, (path, s) in enumerate(paths):
            si = np.linspace(0, s[-1], n_along)
            ribbon[:, k] = np.stack([np.interp(si, s, path[:, i]) for i in range(3)], axis=1)
        # Rows 0 and -1 are the bodice's vertices; the rows between are new.
        index = np.empty((n_along, len(front)), np.int64)
        index[0], index[-1] = front, back
        index[1:-1] = count + np.arange((n_along - 2) * len(front)).reshape(n_along - 2, -1)
        count += (n_along - 2) * len(front)
        f = index.reshape(-1)[grid_faces(n_along, len(front), periodic=False)]
        vs.append(_push_out(ribbon[1:-1].reshape(-1, 3), scene, lift))
        fs.append(_wound_like(f, faces))
    return np.concatenate(vs), np.concatenate(fs)


def _wound_like(new: np.ndarray, old: np.ndarray) -> np.ndarray:
    """``new`` faces (F, 3) flipped if they repeat a directed edge of ``old`` (F0, 3): two
    neighbours that agree on orientation use each shared edge in opposite directions."""
    key = lambda f: set(map(tuple, f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2).tolist()))  # noqa: E731
    if key(new) & key(old):
        return new[:, ::-1].copy()
    return new


def _add_sleeve(cfg, fit, res, vertices, faces, side):
    """A sleeve lofted from the armhole on ``side`` (+1 left, -1 right) to a cuff.

    Rows blend each armhole vertex into its cuff point (the cuff's angles around the arm follow
    the armhole's arc length, so the sleeve never twists over itself), then move out from the
    arm's axis where they would come closer to the arm than the clearance.
    """
    skel = mannequin_skeleton(fit.shape)
    pos = skel.rest_positions().astype(np.float64)
    prefix = "Left" if side > 0 else "Right"
    s0, e0 = pos[skel.index(f"{prefix}Arm")], pos[skel.index(f"{prefix}ForeArm")]
    d = (e0 - s0) / np.linalg.norm(e0 - s0)
    e1 = np.cross(d, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)

    def cyl(p, origin):
        rel = p - origin
        t = rel @ d
        q = rel - t[:, None] * d
        return t, np.arctan2(q @ e2, q @ e1), np.linalg.norm(q, axis=1)

    loops = [lp for lp in boundary_loops(faces) if side * vertices[lp, 0].mean() > 0.05]
    if len(loops) != 1:
        raise InputError(f"top: expected one armhole on side {side:+g}, found {len(loops)}")
    loop = loops[0]
    centre = vertices[loop].mean(axis=0)

    def angles(lp):
        psi = cyl(vertices[lp], centre)[1]
        return psi, np.angle(np.exp(1j * np.diff(np.r_[psi, psi[0]])))

    psi, turn = angles(loop)
    if abs(turn.sum()) < np.pi:
        raise InputError("top: the armhole does not go around the arm")
    if turn.sum() < 0:  # walk it counter-clockwise about the arm
        loop = loop[::-1]
        psi, turn = angles(loop)
    ring_pts = vertices[loop]
    psi = psi[0] + np.r_[0.0, np.cumsum(turn[:-1])]
    if (np.diff(psi) <= 0).any():  # not star-shaped about its centre: follow the arc length
        seg = np.linalg.norm(np.diff(ring_pts, axis=0), axis=1)
        closing = np.linalg.norm(ring_pts[0] - ring_pts[-1])
        psi = psi[0] + 2 * np.pi * np.r_[0.0, np.cumsum(seg)] / (seg.sum() + closing)
    arm = fit.vertices[fit.arms & (side * fit.vertices[:, 0] > 0)]
    at, _, ar = cyl(arm, s0)

    def least(tq):
        """Radius (m) the sleeve keeps around the arm axis at distances ``tq`` along it."""
        near = np.abs(at[None, :] - tq[:, None]) < _ARM_WINDOW
        r = np.where(near, ar[None, :], 0.0).max(axis=1)
        return np.where(tq > _ARM_WINDOW, r + cfg.clearance + cfg.ease, 0.0)

    cuff_r = float(least(np.array([cfg.sleeve]))[0]) + cfg.sleeve_ease
    around = np.cos(psi)[:, None] * e1 + np.sin(psi)[:, None] * e2
    cuff = s0 + cfg.sleeve * d + cuff_r * around
    n_rows = max(2, math.ceil(np.linalg.norm(cuff - ring_pts, axis=1).max() / res) + 1)
    w = np.linspace(0, 1, n_rows)[1:, None, None]
    pts = ((1 - w) * ring_pts[None] + w * cuff[None]).reshape(-1, 3)
    pts = _push_out(pts, _body_scene(fit), cfg.clearance + cfg.ease)
    index = np.empty((n_rows, len(loop)), np.int64)
    index[0] = loop
    index[1:] = len(vertices) + np.arange((n_rows - 1) * len(loop)).reshape(n_rows - 1, -1)
    f = index.reshape(-1)[grid_faces(n_rows, len(loop), periodic=True)]
    return np.concatenate([vertices, pts]), np.concatenate([faces, _wound_like(f, faces)])
