"""The simulation stage's one config record, and the fabric presets it names."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from numbers import Integral, Real

import numpy as np

from core.errors import InputError


@dataclass(frozen=True)
class Fabric:
    """Material of a garment, in the units newton's VBD cloth solver takes (SI)."""

    name: str
    """Preset name, for reports."""
    density: float
    """Areal density, kg/m^2 (silk about 0.05, cotton 0.15, denim 0.4)."""
    stretch_ke: float
    """Membrane (StVK) stiffness, N/m: resistance to stretch (newton ``tri_ke`` / ``tri_ka``)."""
    stretch_kd: float
    """Membrane damping, in newton's units (``tri_kd``)."""
    bend_ke: float
    """Bending stiffness, N*m (newton ``edge_ke``): silk drapes, denim stands."""
    bend_kd: float
    """Bending damping (``edge_kd``)."""
    friction: float
    """Coulomb friction coefficient against the body."""
    max_strain: float
    """Largest edge stretch ((l - l0) / l0) the fabric may show (woven fabric gives little);
    ``SimConfig.blowup_strain`` times it marks a blown-up frame."""


#: Fabric presets by name. Stiffness rises and drape falls from silk to denim.
FABRICS: dict[str, Fabric] = {
    "silk": Fabric("silk", 0.06, 2.0e3, 1.0e-3, 2.0e-6, 1.0e-7, 0.2, 0.25),
    "cotton": Fabric("cotton", 0.15, 5.0e3, 2.0e-3, 2.0e-5, 1.0e-6, 0.35, 0.2),
    "denim": Fabric("denim", 0.40, 1.5e4, 5.0e-3, 2.0e-4, 1.0e-5, 0.5, 0.15),
}


#: Named (substeps, iterations) trade-offs of Style3D. Too few iterations leave the cloth softer
#: than it is: on a spin the hem lags the waist and the skirt winds up. ``final`` is the
#: trustworthy one (a spin flares the skirt); ``dng bench sim`` measures each against a run twice
#: as fine (docs/decisions.md, "QUALITY").
QUALITY = {"draft": (2, 8), "medium": (8, 16), "final": (16, 32)}

#: Chebyshev weight of a single surface's Style3D iterations (``SimConfig.chebyshev_rho=None``):
#: accelerated, a spun proxy's hem keeps close to a finer run's radius; 0.999 blew up a lead-in
#: (docs/decisions.md, "CHEBYSHEV_RHO").
CHEBYSHEV_RHO = 0.99

#: Cloth solvers :func:`core.sim.simulate.simulate` drives: newton's Style3D and VBD, and ours,
#: implicit steps solved by Newton's method (:mod:`core.sim.implicit`, a single surface only).
SOLVERS = ("style3d", "vbd", "implicit")
#: How the implicit solver's Newton updates are measured (``SimConfig.implicit_norm``).
IMPLICIT_NORMS = ("max", "rms")

#: The Python types each of :class:`SimConfig`'s annotations admits (an int for a float).
_SETTING_TYPES = {
    "int": Integral, "float": Real, "float | None": (Real, type(None)),
    "bool | None": (bool, np.bool_, type(None)), "bool": (bool, np.bool_), "str": str,
}  # fmt: skip


def fabric(name: str) -> Fabric:
    """The preset called ``name``; ``InputError`` listing the choices otherwise."""
    try:
        return FABRICS[name]
    except KeyError:
        raise InputError(f"unknown fabric {name!r}; choose one of {', '.join(FABRICS)}") from None


@dataclass(frozen=True)
class SimConfig:
    """Everything that decides a garment simulation. The GUI edits this same record."""

    fabric: str = "cotton"
    """Fabric preset name (see :data:`FABRICS`)."""
    solver: str = "style3d"
    """``style3d`` (newton's projective-dynamics solver with a PCG global step: converges to
    low strain in few iterations; the default) or ``vbd`` (vertex block descent: local
    Gauss-Seidel, needs many more iterations before the fabric stops stretching) or
    ``implicit`` (ours, :mod:`core.sim.implicit`: implicit steps (``implicit_order``) solved by
    Newton's method with a direct sparse solve, each to ``implicit_tol``; a single surface only;
    converged at Style3D medium's cost at 2 steps a frame, ``implicit_norm="rms"``: docs/decisions.md,
    "sim_solver = implicit")."""
    substeps: int = 16
    """Solver steps per 1/30 s of motion. Clips at other frame rates get the same physical time
    step or a finer one: ``ceil(substeps * 30 / fps)`` steps per frame, at least one."""
    iterations: int = 32
    """Non-linear solver iterations per step. The defaults (16 x 32, :data:`QUALITY` ``final``)
    are the trustworthy setting (a spin flares the skirt instead of winding it up); ``medium``
    (8 x 16) costs a quarter, ``draft`` (2 x 8) a thirtieth. With ``solver="implicit"``: the
    most Newton iterations a step runs (it stops sooner at ``implicit_tol``)."""
    implicit_order: int = 2
    """``solver="implicit"``: 1 integrates by backward Euler (as Style3D does), 2 by BDF2
    (second order: a swing's numerical damping falls with the step's square, not the step;
    a step after one of another length is backward Euler). 2 by that property (the swinging
    sheet of ``tests/test_sim_implicit.py``), not by any clip's figures: on the quick proxy
    both orders are as far from their 2x runs as from their floor (README)."""
    implicit_tol: float = 1.0e-4
    """``solver="implicit"``: a step's Newton iterations stop when the update, measured by
    ``implicit_norm``, is under this (metres)."""
    implicit_norm: str = "max"
    """``solver="implicit"``: how a Newton update meets ``implicit_tol``: ``max``, its largest
    vertex's; ``rms``, its root mean square over the vertices. Where the cloth buckles, a few
    vertices can keep moving from one fold to the next for many iterations while the rest has
    settled; ``rms`` stops there (docs/decisions.md, "sim_solver = implicit", measures both)."""
    linear_iterations: int = 10
    """Conjugate-gradient iterations of each Style3D iteration's linear solve (newton's
    default is 10). Too few and the waist's motion does not reach the hem within a step: the
    skirt lags the body and winds up on a spin (see :data:`QUALITY`)."""
    chebyshev_rho: float | None = None
    """Spectral radius that weighs the Chebyshev acceleration of the Style3D iterations
    (:mod:`core.sim.style3d`); 0 runs them plain, as newton does. Closer to 1 extrapolates more:
    the same iterations get further, until it overshoots. ``None``: :data:`CHEBYSHEV_RHO` for a
    single surface (a proxy), 0 with cloth-cloth contact (extrapolated layers 4 mm apart blew
    up the multilayer skirt's first step)."""
    self_collision: bool | None = None
    """Cloth-cloth contact. ``None``: on when the garment has several pieces (layers, frills:
    where layers touch), off for a single surface such as a proxy (nothing to collide with).
    Costs extra time per step."""
    transition_s: float = 1.0
    """Seconds over which the body blends from the garment's rest pose (the mannequin's A-pose)
    to the clip's first frame, before the clip starts."""
    settle_s: float = 0.5
    """Seconds the body then holds the first frame, so the garment is at rest at frame 0."""
    pin_distance: float = 0.03
    """Vertices within this distance (metres) of the garment's top boundary loop (a skirt's
    waistband) are pinned: skinned rigidly to the nearest torso bone, moved every step."""
    arm_colliders: bool | None = None
    """Whether the arms collide with the garment. ``None``: only for garments reaching above
    the chest (dresses, tops). A skirt leaves them out: an arm pressed to the hip would pinch
    the fabric between two rigid colliders, with nowhere to go, and tear it; the hands pass
    through the skirt instead."""
    collision_margin: float = 0.004
    """Thickness kept between cloth and body (metres): the particle radius in contacts."""
    layer_friction: float = 0.1
    """Friction against the body of a proxy kept off it by the layers beneath it (``thickness``
    of :func:`core.sim.simulate.simulate`), in place of the fabric's: those layers slide. The
    fabric's snagged the quick proxy on a kicking leg (docs/decisions.md, "layer_friction")."""
    layer_ke: float = 10.0
    """Stiffness (N/m per vertex) with which the layers beneath a proxy vertex (``thickness``
    of :func:`core.sim.simulate.simulate`) push back once the body presses into them, beyond
    the margin met at ``contact_ke`` (the implicit solver; Style3D's contact has one stiffness).
    Frills and the air between them give: as a rigid shell they held a skirt on the hips after
    a kick (docs/decisions.md, "The layers beneath the proxy are soft")."""
    compression: float = 1.0
    """The membrane's stiffness in compression, as a fraction of its stiffness in stretch (the
    implicit solver). 1 for a garment of its own: a coarse one (a 96-vertex skirt, one step a
    frame) blew up at 0.01. A coarse triangle stands for cloth that buckles into folds finer
    than it, which costs little: see ``layer_compression``."""
    layer_compression: float = 0.003
    """``compression`` for a proxy kept off the body by its layers (``thickness``): at 1 the
    folds a kick, a kneel or a squat made in the quick proxy were held in place, and at 0.01,
    with converged steps, a fold tucked up onto the hips after a squat or a kick stayed there
    (docs/decisions.md, "The proxy's cloth")."""
    rest_bending: bool = True
    """Bending toward the garment's rest shape (each hinge's rest bend turned with the cloth),
    not toward flat (the implicit solver): what holds a shape the soft membrane cannot."""
    layer_bending: float = 10.0
    """A proxy kept off the body by its layers (``thickness``) bends this many times as stiffly
    as its fabric (the implicit solver): it stands for the layers and frills beneath it."""
    layer_full_bending: bool = True
    """A proxy kept off the body by its layers (``thickness``) puts bending's whole Hessian in
    each Newton step's matrix, not its diagonal alone (the implicit solver). At ``layer_bending``
    times the fabric's bending, a step with the diagonal met its tolerance long before its bends
    settled: 26 to 31 mm mean from its 2x run on quick's clips, 6 to 9 with the whole Hessian,
    at about 1.4x the cost (docs/decisions.md, "What counts as converged")."""
    layer_release: float = 0.01
    """How deep (metres) past its margin's outer edge the body's push on a proxy kept off the
    body by its layers stops growing (the implicit solver): cloth that a fast limb carried deep
    into a capsule is pulled out by its own tension instead of held there, stretched. Not for
    other garments: a high kick pushes a long skirt harder than that, rightly."""
    self_contact_thickness: float = 0.003
    """Distance (metres) that cloth-cloth contacts keep between two pieces of cloth (Style3D).
    It must stay below the gaps a layered garment is built with (the built-in templates stack
    their parts 4 mm apart): parts closer than this start in contact and are shoved apart from
    the first step, and where one of them is pinned or sewn (kinematic) the push never ends."""
    contact_gap: float = 0.01
    """Extra distance (metres) at which body contacts are detected ahead of touching, so a fast
    limb is seen before it passes through the cloth within one step."""
    damping: float = 0.0
    """Velocity damping (1/s): every step multiplies the cloth's velocities by
    ``exp(-damping * dt)``, the same drag per second at any step size (air drag is small; the
    solver's own fixed per-step drag is divided out, see ``core.sim.simulate``)."""
    contact_ke: float = 1.0e4
    """Body-contact stiffness, N/m."""
    max_retries: int = 2
    """Times a frame that blows up is retried, each with twice the steps, before giving up."""
    retry_depth: float | None = 0.005
    """A frame that leaves a free vertex deeper than this (metres) inside the body's capsules,
    and deeper than any was at the frame's start, is re-run with twice the steps (up to
    ``max_retries`` times; the finest attempt is kept, not an error): a limb that moved through
    the cloth in one step. Only those frames pay. ``None``: never (docs/decisions.md, "A fast
    limb through the hem")."""
    blowup_strain: float = 5.0
    """A frame whose largest edge strain passes this multiple of the fabric's ``max_strain``
    counts as blown up (numerical blow-ups give strains of several times the rest length; a
    fold pinched between two colliders stays below this)."""
    max_speed: float = 30.0
    """A vertex faster than this (m/s) counts as a blow-up (a body part rarely moves faster
    than 10 m/s)."""
    device: str = "cpu"
    """Warp device: ``cpu`` or ``cuda`` / ``cuda:0``."""

    def __post_init__(self) -> None:
        for f in fields(self):  # a setting from the command line (--set) may be any JSON value
            value = getattr(self, f.name)
            if not isinstance(value, _SETTING_TYPES[f.type]) or (
                isinstance(value, bool) and "bool" not in f.type
            ):
                raise InputError(f"simulation setting {f.name}={value!r} must be of type {f.type}")
        fabric(self.fabric)
        if self.solver not in SOLVERS:
            raise InputError(f"unknown solver {self.solver!r}; choose one of {', '.join(SOLVERS)}")
        checks = {
            "substeps": self.substeps >= 1,
            "iterations": self.iterations >= 1,
            "linear_iterations": self.linear_iterations >= 1,
            "implicit_tol": self.implicit_tol > 0,
            "implicit_order": self.implicit_order in (1, 2),
            "implicit_norm": self.implicit_norm in IMPLICIT_NORMS,
            "chebyshev_rho": self.chebyshev_rho is None or 0 <= self.chebyshev_rho < 1,
            "transition_s": self.transition_s >= 0,
            "settle_s": self.settle_s >= 0,
            "pin_distance": self.pin_distance >= 0,
            "collision_margin": self.collision_margin > 0,
            "self_contact_thickness": self.self_contact_thickness > 0,
            "contact_ke": self.contact_ke > 0,
            "layer_release": self.layer_release > 0,
            "layer_ke": self.layer_ke >= 0,
            "compression": 0 < self.compression <= 1,
            "layer_compression": 0 < self.layer_compression <= 1,
            "layer_bending": self.layer_bending > 0,
            "contact_gap": self.contact_gap >= 0,
            "damping": self.damping >= 0,
            "max_retries": self.max_retries >= 0,
            "retry_depth": self.retry_depth is None or self.retry_depth >= 0,
            "max_speed": self.max_speed > 0,
            "blowup_strain": self.blowup_strain >= 1,
        }
        for name, ok in checks.items():
            if not ok:
                raise InputError(
                    f"simulation setting {name}={getattr(self, name)!r} is out of range"
                )

    @property
    def material(self) -> Fabric:
        return fabric(self.fabric)

    def steps_per_frame(self, fps: float) -> int:
        """Solver steps per motion frame at ``fps`` (constant physical step across rates)."""
        return max(1, math.ceil(self.substeps * 30.0 / fps - 1e-9))

    def as_dict(self) -> dict:
        d = asdict(self)
        d["fabric_params"] = asdict(self.material)
        return d
