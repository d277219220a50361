"""The detailed target's hanging pieces simulated as cloth on its embedded body (``tiers``).

Embedding the target in the simulated proxy (:mod:`core.sim.embed`) makes its image a function
of the proxy's current frame: the frill tiers of a layered skirt keep their rest offsets from
the proxy's envelope, so they cannot swing, lag or flare on their own, which is what the paper's
motion features and temporal block are there to predict. Simulating the whole layered target
as cloth costs more than quick can spend (docs/decisions.md, "target_mode"), so this simulates
only what the proxy collapses:

- **the tiers** are the garment's loose pieces, the parts no waist pin holds that are sewn to
  the cloth beside them (:func:`core.sim.pins.find_seams`: a layered skirt's frills at each
  layer's hem). Each is simulated as cloth by the implicit solver (:mod:`core.sim.implicit`):
  inertia, gravity, the fabric's membrane and bending, the body's capsules with friction;
- **their seams** (each piece's band along its top loop, sewn over its host's hem) are
  kinematic: where the embedding carries them, every substep (interpolated between frames);
- **the layer beneath**: each step, a tier vertex near the embedded cloth it hangs over
  (within ``layer_reach`` sideways of the nearest cloth vertex's normal, farther than
  ``seam_clear`` from its seam) gets that vertex's tangent plane at the step's end as a
  one-sided penalty contact in the solve (``layer_margin`` in front of it, at the body's
  contact stiffness);
- **damping** of the tiers' motion relative to the embedded tiers' (``damping``);
- everything else (the layers, the waistband) stays embedded.

The tiers start where the embedding puts them, at its velocity: the clip starts in motion
(the proxy had its lead-in), and a tier held still while its seam moves would be yanked.

The result is the garment's positions per frame, the embedded ones with the tiers replaced.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from core.body.shape import BodyShape, mannequin_skeleton
from core.errors import InputError
from core.mesh import boundary_loops, vertex_normals
from core.sim.config import SimConfig, fabric
from core.sim.implicit import ImplicitCloth, cloth_rest
from core.sim.pins import _components, find_pins, find_seams


@dataclass(frozen=True)
class TierConfig:
    """How the tiers are simulated (one record for the stage and its report)."""

    substeps: int = 2
    """Implicit steps per frame at the clip's frame rate (the proxy's quick simulation: 2)."""
    tol: float = 3.0e-4
    """Newton update (metres) a step stops under ..."""
    norm: str = "rms"
    """... measured by its root mean square over the tier vertices (``rms``) or its largest
    vertex (``max``)."""
    iterations: int = 16
    """The most Newton iterations a step runs."""
    damping: float = 5.0
    """Damping (1/s) of the tiers' velocity relative to the embedded tiers' (the fabric's own
    damping and the air's on a flap): each step multiplies the difference by
    ``exp(-damping * dt)``."""
    fabric: str = "cotton"
    """Fabric preset (``core.sim.config.FABRICS``): the project's."""
    bend_ke: float | None = 2.0e-6
    """Bending stiffness (N m); None: the fabric's. A tenth of cotton's (silk's): frills are
    cut from a light fabric, and the solver's quadratic bending pulls a curved rest shape flat
    (docs/decisions.md, "target_mode = tiers")."""
    friction: float | None = None
    """Coulomb coefficient against the body; None: the fabric's."""
    layer_margin: float = 0.003
    """Metres a tier vertex keeps in front of the embedded cloth beneath it."""
    layer_depth: float = 0.008
    """Deepest (metres) a tier vertex may lie behind the cloth beneath it and still be pushed
    out in front of it; deeper, it is on that cloth's other side (between two layers)."""
    seam_clear: float = 0.02
    """Tier vertices within this many metres of their seam at rest take no layer contact: the
    seam holds them on their host, whose folds (where the proxy crumples) turn its normals."""
    layer_reach: float = 0.7
    """Farthest a tier vertex lies sideways from its nearest embedded vertex's normal for that
    vertex's cloth to count as beneath it, in the cloth's median edge lengths (a triangle's
    inside is within 0.7 of one of its corners). The cloth's edge vertices (a hem's) are no
    candidates, so past an edge by more than this the cloth is not beneath."""
    perturbation: float = 0.0
    """Standard deviation (metres) of a seeded random nudge of the tiers' starting positions:
    a second run nudged 10 um measures the tiers' floor (their own sensitivity)."""
    seed: int = 0
    """Seed of that nudge."""
    floor_frames: int = 50
    """The project's stage simulates each clip's first this many frames a second time, nudged
    10 um, for the tiers' floor (the report's "dynamics of its own" beside it); 0: none."""

    def __post_init__(self) -> None:
        fabric(self.fabric)  # InputError for an unknown name
        if self.substeps < 1 or self.iterations < 1:
            raise InputError("tier substeps and iterations must be at least 1")
        if not (self.tol > 0 and min(self.damping, self.perturbation, self.floor_frames) >= 0):
            raise InputError("tier tol must be > 0; damping, perturbation, floor_frames >= 0")


@dataclass(frozen=True)
class Tiers:
    """A garment's hanging pieces and what holds them (:func:`find_tiers`).

    Attributes
    ----------
    free : (N,) int64 garment vertices simulated (every vertex of the loose pieces), ascending
    faces : (Ft, 3) int64 the pieces' triangles, in indices into ``free``
    pinned : (P,) int64 positions in ``free`` of the seams' vertices, ascending: kinematic,
        where the embedding carries them
    beneath : (M,) int64 garment vertices the tiers collide with (the rest of the garment)
    beneath_faces : (Fb, 3) int64 the garment faces among those (for their normals)
    pieces : int loose pieces found
    """

    free: np.ndarray
    faces: np.ndarray
    pinned: np.ndarray
    beneath: np.ndarray
    beneath_faces: np.ndarray
    pieces: int


def find_tiers(
    vertices: np.ndarray, faces: np.ndarray, shape: BodyShape, seam_band: float = 0.012
) -> Tiers:
    """The loose pieces of a garment at rest on the mannequin of ``shape`` (see the module), and
    their seams: each piece's vertices within ``seam_band`` metres of its top boundary loop
    (where :func:`core.sim.pins.find_seams` sews it; a frill's top overlaps its layer's hem).

    vertices : (V, 3) float rest positions; faces : (F, 3) int. A garment without loose pieces
    gives empty ``free`` (nothing to simulate: the target stays embedded)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    sim = SimConfig()
    pins = find_pins(v, f, mannequin_skeleton(shape), sim.pin_distance, shape.height)
    seams = find_seams(v, f, pins.indices, sim.pin_distance)
    label = _components(len(v), f)
    pieces = np.unique(label[seams.indices])
    loose = np.isin(label, pieces)
    free = np.flatnonzero(loose)
    local = np.full(len(v), -1, np.int64)
    local[free] = np.arange(len(free))
    tops = []
    for c in pieces:
        loops = [lp for lp in boundary_loops(f) if label[lp[0]] == c]
        top = loops[int(np.argmax([v[lp, 1].mean() for lp in loops]))]
        members = np.flatnonzero(label == c)
        near = cKDTree(v[top]).query(v[members])[0] <= seam_band
        tops.append(members[near])
    seam = np.sort(np.concatenate(tops)) if tops else np.zeros(0, np.int64)
    return Tiers(
        free=free,
        faces=local[f[loose[f[:, 0]]]],
        pinned=local[seam],
        beneath=np.flatnonzero(~loose),
        beneath_faces=f[~loose[f[:, 0]]],
        pieces=len(pieces),
    )


@dataclass(frozen=True)
class TierRun:
    """What :func:`simulate_tiers` measured."""

    seconds: float
    newton_mean: float
    """Mean Newton iterations per step."""
    layer_contacts: float
    """Mean fraction of tier vertices given a layer contact plane per step."""
    steps: int = 0


def _layer_planes(
    x: np.ndarray,
    movable: np.ndarray,
    cloth: np.ndarray,
    normals: np.ndarray,
    reach: float,
    cfg: TierConfig,
) -> tuple[tuple, np.ndarray]:
    """The contact planes of tier vertices ``x`` (N, 3) (the step's start) against the embedded
    ``cloth`` (M, 3) with unit ``normals`` (M, 3) (the step's end): each ``movable`` (N,) vertex
    within ``reach`` (metres) sideways of its nearest cloth vertex's normal, in front of it by less
    than ``layer_margin`` plus a centimetre (what a step can close) or behind it by less than
    ``layer_depth``. Returns the planes (:meth:`core.sim.implicit.ImplicitCloth.step`) and the
    signed heights (N,) of every vertex over its nearest cloth (NaN where that is not beneath)."""
    _, j = cKDTree(cloth).query(x)
    d = x - cloth[j]
    n = normals[j]
    height = (d * n).sum(1)
    side = np.linalg.norm(d - height[:, None] * n, axis=1)
    beneath = (side < reach) & (height > -cfg.layer_depth) & movable
    near = beneath & (height < cfg.layer_margin + 0.01)
    vi = np.flatnonzero(near)
    return (vi, cloth[j[vi]], n[vi], cfg.layer_margin), np.where(beneath, height, np.nan)


def _outward(normals: np.ndarray, points: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Signs (per vertex, +1 or -1) that turn each connected part's normals away from the
    garment's vertical axis on the whole (meshes may wind either way)."""
    centre = points.mean(0)
    radial = points - centre
    radial[:, 1] = 0.0
    sign = np.ones(len(points))
    for c in np.unique(labels):
        m = labels == c
        if (normals[m] * radial[m]).sum() < 0:
            sign[m] = -1.0
    return sign


class _Beneath:
    """The embedded cloth the tiers hang over: its vertices and outward unit normals per frame,
    its edge vertices (a hem's) left out (:attr:`TierConfig.layer_reach`)."""

    def __init__(self, rest: np.ndarray, tiers: Tiers):
        self.idx = tiers.beneath
        edge = np.zeros(len(rest), bool)
        for loop in boundary_loops(tiers.beneath_faces):
            edge[loop] = True
        self.inner = ~edge[self.idx]
        local = np.full(len(rest), -1, np.int64)
        local[self.idx] = np.arange(len(self.idx))
        self.faces = local[tiers.beneath_faces]
        pts = rest[self.idx]
        labels = _components(len(self.idx), self.faces)
        self.sign = _outward(vertex_normals(pts, self.faces), pts, labels)[:, None]
        edges = self.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        #: the cloth's median edge length (metres), the unit of ``TierConfig.layer_reach``
        self.edge = float(np.median(np.linalg.norm(pts[edges[:, 0]] - pts[edges[:, 1]], axis=1)))

    def at(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(M', 3) points and unit normals of the cloth for garment positions (V, 3)."""
        pts = np.asarray(frame, np.float64)[self.idx]
        return pts[self.inner], (self.sign * vertex_normals(pts, self.faces))[self.inner]


def _contact_mask(x0: np.ndarray, tiers: Tiers, cfg: TierConfig) -> np.ndarray:
    """(N,) bool: the tier vertices that take the layer contact (farther than ``seam_clear``
    from their seam at rest ``x0`` (N, 3))."""
    far = cKDTree(x0[tiers.pinned]).query(x0)[0] > cfg.seam_clear
    far[tiers.pinned] = False
    return far


def layer_crossings(
    positions: np.ndarray, rest: np.ndarray, tiers: Tiers, config: TierConfig = TierConfig()
) -> tuple[float, float]:
    """How far the simulated tiers went through the embedded cloth beneath them: the fraction
    of (frame, vertex) pairs behind it and the deepest (metres), over the vertices that take
    the layer contact. positions : (T, V, 3) the garment's. Behind by more than
    ``layer_depth`` counts as the cloth's other side (between two layers), not as a crossing."""
    rest = np.asarray(rest, np.float64)
    if not len(tiers.free):
        return 0.0, 0.0
    beneath = _Beneath(rest, tiers)
    mask = _contact_mask(rest[tiers.free], tiers, config)
    behind, depth, count = 0, 0.0, 0
    for frame in np.asarray(positions, np.float64):
        pts, nrm = beneath.at(frame)
        _, h = _layer_planes(
            frame[tiers.free], mask, pts, nrm, config.layer_reach * beneath.edge, config
        )
        under = h < 0  # NaN (not beneath) compares False
        behind += int(under.sum())
        count += int(mask.sum())
        depth = max(depth, float(-h[under].min()) if under.any() else 0.0)
    return behind / max(count, 1), depth


def distances(a: np.ndarray, b: np.ndarray, vertices: np.ndarray | None = None) -> dict:
    """Mean and 95th percentile (mm) of the per-vertex distances between two runs of the same
    garment (T, V, 3), over every frame and the given ``vertices`` (default all)."""
    d = np.linalg.norm(np.asarray(a, np.float64) - np.asarray(b, np.float64), axis=-1)
    if vertices is not None:
        d = d[:, vertices]
    return {"mean_mm": float(1e3 * d.mean()), "p95_mm": float(1e3 * np.percentile(d, 95))}


def simulate_tiers(
    embedded: np.ndarray,
    faces: np.ndarray,
    rest: np.ndarray,
    tiers: Tiers,
    capsule_ends: np.ndarray,
    radii: np.ndarray,
    fps: float,
    config: TierConfig = TierConfig(),
    collision_margin: float = SimConfig.collision_margin,
    contact_ke: float = SimConfig.contact_ke,
) -> tuple[np.ndarray, TierRun]:
    """The garment's motion with its tiers simulated on its embedded motion.

    Parameters
    ----------
    embedded : (T, V, 3) float the garment embedded in its proxy's simulation
    faces : (F, 3) int; rest : (V, 3) float its rest positions
    tiers : :func:`find_tiers` of the garment
    capsule_ends : (T, K, 2, 3) float the body's capsules per frame; radii : (K,) float
    fps : frames per second of ``embedded``

    Returns
    -------
    positions : (T, V, 3) float32, ``embedded`` with the tier vertices simulated
    run : TierRun
    """
    e = np.asarray(embedded, np.float64)
    ends = np.asarray(capsule_ends, np.float64)
    if e.ndim != 3 or e.shape[1:] != np.shape(rest) or len(ends) != len(e):
        raise InputError(
            f"tiers need (T, {len(rest)}, 3) positions and (T, K, 2, 3) capsules, got "
            f"{e.shape} and {ends.shape}"
        )
    out = e.astype(np.float32)
    if not len(tiers.free):
        return out, TierRun(0.0, 0.0, 0.0)
    start = time.perf_counter()
    fab = fabric(config.fabric)
    x0 = np.asarray(rest, np.float64)[tiers.free]
    bend = fab.bend_ke if config.bend_ke is None else config.bend_ke
    cloth_data = cloth_rest(x0, tiers.faces, fab.density, bend)
    mu = np.full(len(radii), fab.friction if config.friction is None else config.friction)
    margin = np.full(len(tiers.free), collision_margin)
    cloth = ImplicitCloth(
        cloth_data, fab.stretch_ke, contact_ke, margin, mu, np.asarray(radii, np.float64),
        tiers.pinned, config.tol, config.iterations, config.norm, full_bending=True,
    )  # fmt: skip
    beneath = _Beneath(np.asarray(rest, np.float64), tiers)
    contact = _contact_mask(x0, tiers, config)
    x = e[0, tiers.free].copy()
    if config.perturbation > 0:
        rng = np.random.default_rng(config.seed)
        x += config.perturbation * rng.standard_normal(x.shape)
    # the embedded tiers' own velocity: the clip starts in motion (the proxy had its lead-in)
    vel = (e[min(1, len(e) - 1), tiers.free] - e[0, tiers.free]) * fps
    dt = 1.0 / (fps * config.substeps)
    before = None
    contacts, steps = 0, 0

    def advance(x, vel, before, ends_a, ends_b, frame, cloth_b, normals_b, x_from):
        nonlocal contacts, steps
        planes, _ = _layer_planes(
            x, contact, cloth_b, normals_b, config.layer_reach * beneath.edge, config
        )
        pinned_to = frame[tiers.free[tiers.pinned]]
        xn, vn = cloth.step(x, vel, pinned_to, ends_a, ends_b, dt, before, planes)
        if not np.isfinite(xn).all():
            raise FloatingPointError("the tiers' simulation blew up (non-finite positions)")
        if config.damping > 0:
            carried = (frame[tiers.free] - x_from) / dt  # the embedded tiers' velocity
            vn = carried + (vn - carried) * np.exp(-config.damping * dt)
        contacts += len(planes[0])
        steps += 1
        return xn, vn, (x, vel)

    out[0, tiers.free] = x  # the first frame is the start; each later one a frame's steps on
    for t in range(1, len(e)):
        a, b = e[t - 1], e[t]
        ea, eb = ends[t - 1], ends[t]
        for s in range(config.substeps):
            w0, w1 = s / config.substeps, (s + 1) / config.substeps
            frame = a + (b - a) * w1
            pts, nrm = beneath.at(frame)
            x, vel, before = advance(
                x, vel, before, ea + (eb - ea) * w0, ea + (eb - ea) * w1,
                frame, pts, nrm, (a + (b - a) * w0)[tiers.free],
            )  # fmt: skip
        out[t, tiers.free] = x
    seconds = time.perf_counter() - start
    its = cloth.newton_iterations
    return out, TierRun(
        seconds=seconds,
        newton_mean=float(np.mean(its)) if its else 0.0,
        layer_contacts=contacts / max(steps, 1) / len(tiers.free),
        steps=steps,
    )
