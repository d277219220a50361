"""Cloth simulation of a garment on the moving mannequin, with newton's VBD solver (warp).

Scene: the garment mesh as cloth (membrane + dihedral bending, the fabric preset's density and
stiffness), gravity along -Y, the body as kinematic capsules
(:mod:`core.body.colliders`) posed every solver step, the waistband/neckline pinned to the
torso bones and loose pieces (frills, a sash, a bow) sewn to the part they lie on
(:mod:`core.sim.pins`). Solver: newton's Style3D (implicit projective dynamics
with a PCG global step) by default: stable at the few large steps a CPU can afford, and its
global step holds the fabric's stretch to a fraction of a percent in a few iterations. VBD
(vertex block descent) is the alternative; on the 1.9k long skirt it needed 16 iterations to
bring the mean edge strain down to 4 % (Style3D: 0.05 %). XPBD with springs blew up on the
same skirt at 10 steps per frame.

Every clip frame is checked before it is kept (finite, speed, edge strain); a frame that fails
is re-run from its start with twice the steps (``max_retries`` times) before
:class:`SimulationError` stops the run. A frame that leaves the cloth deeper inside the body
than ``SimConfig.retry_depth`` (and deeper than at its start: a limb moved through it within
one step) is re-run finer the same way, and its finest attempt is kept. Nothing is written by
this module: the caller saves the returned :class:`~core.sim.cache.SimCache`, which therefore never holds garbage.

On CPU, warp kernels run serially, so the same inputs give bit-identical caches. On CUDA the
VBD solver is built with run-to-run deterministic atomics; Style3D's CUDA reductions are
not guaranteed bitwise reproducible (measure before relying on it).
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from importlib.metadata import PackageNotFoundError, version
from typing import TYPE_CHECKING

import numpy as np

from core.body.colliders import (
    BodyCapsules,
    arms_collide,
    capsule_distance,
    closest_on_segments,
    garment_capsules,
    is_arm,
    penetration_depths,
    pose_capsules,
)
from core.body.shape import BodyShape, mannequin_skeleton
from core.body.skinning import motion_arrays
from core.errors import InputError
from core.mesh import Mesh, count_components, unique_edges
from core.sim.cache import SimCache
from core.sim.config import CHEBYSHEV_RHO, SimConfig
from core.sim.drive import BodyDrive, body_drive
from core.sim.pins import Pins, Seams, find_pins, find_seams
from core.sim.sanity import PELVIS_JOINTS, Pelvis, band_measures

if TYPE_CHECKING:
    from core.sim.implicit import ImplicitScene

#: Weight of a kinematic particle in Style3D's cloth-cloth contacts (its solver row is 0; a free
#: particle's holds its stretch stiffness and mass / dt^2, orders of magnitude more): small
#: enough to leave those contacts without force, but not 0.
KINEMATIC_CONTACT_WEIGHT = 1.0e-6
#: Style3D multiplies every velocity by this at the end of each step (newton's
#: ``update_velocity``): a drag of 0.002 per step, so 0.48 per second at 8 steps per frame and
#: twice that at 16: finer steps damped more, and no step size converged to one motion.
#: :class:`_Scene` divides it out and applies ``SimConfig.damping`` per second instead.
STYLE3D_VELOCITY_FACTOR = 0.998


#: The solver class each :attr:`SimConfig.solver` runs, as the cache's params name it.
SOLVER_CLASSES = {
    "style3d": "newton.SolverStyle3D",
    "vbd": "newton.SolverVBD",
    "implicit": "core.sim.implicit.ImplicitCloth",
}


class _RecordedLaunches:
    """Warp, as newton's Style3D solver sees it, with every kernel launch recorded once.

    The solver launches the same kernels on the same arrays every iteration; on a CPU packing
    a launch's arguments costs more than running it on a few thousand particles. Here each
    distinct launch (kernel, size, arguments: arrays by address and shape, numbers by value)
    is recorded on first use and replayed after (warp's ``record_cmd``): the same kernels on
    the same data, so the results are bit for bit the same. A launch with any other argument
    (a struct, None) is not recorded. Everything else is warp's own.
    """

    def __init__(self, wp):
        self._wp = wp
        self._cache: dict = {}

    def __getattr__(self, name):
        return getattr(self._wp, name)

    @staticmethod
    def _key(arg):
        if isinstance(arg, (int, float, bool)):
            return (type(arg), arg)
        ptr = getattr(arg, "ptr", None)
        if ptr is not None:
            return ("array", ptr, tuple(arg.shape), tuple(arg.strides), str(arg.dtype))
        return None  # a struct or other object: its contents may change, never replayed

    def launch(self, kernel, dim, inputs=(), outputs=(), device=None, **kwargs):
        args = [self._key(a) for a in (*inputs, *outputs)]
        if kwargs or None in args:
            return self._wp.launch(kernel, dim, inputs, outputs, device=device, **kwargs)
        dims = dim if isinstance(dim, int) else tuple(dim)
        key = (kernel, dims, len(inputs), *args)
        cmd = self._cache.get(key)
        if cmd is None:
            if len(self._cache) > 4096:  # a bound; a run uses a few dozen
                self._cache.clear()
            cmd = self._wp.launch(kernel, dim, inputs, outputs, device=device, record_cmd=True)
            self._cache[key] = cmd
        cmd.launch()


def _record_style3d_launches(wp) -> None:
    """Route the Style3D solver's and its collision handler's launches through
    :class:`_RecordedLaunches` (CPU only: CUDA launches are cheap to issue)."""
    from newton._src.solvers.style3d import solver_style3d
    from newton._src.solvers.style3d.collision import collision

    for module in (solver_style3d, collision):
        if not isinstance(module.wp, _RecordedLaunches):
            module.wp = _RecordedLaunches(wp)


class SimulationError(InputError):
    """The simulation blew up and could not be recovered; nothing was written.

    Attributes
    ----------
    frame : int
        Clip frame that failed (negative: a chunk of the lead-in).
    positions : (V, 3) float32 or None
        The garment as the last attempt left it, for diagnosis only.
    """

    def __init__(self, problem: str, path=None, frame: int = 0, positions=None):
        super().__init__(problem, path)
        self.frame = frame
        self.positions = positions


@dataclass(frozen=True)
class SimReport:
    """How a simulation went: speed, strain, body penetration, retries."""

    frames: int
    vertices: int
    pinned: int
    steps_per_frame: int
    preroll_steps: int
    device: str
    setup_s: float
    """Model build, first-use kernel compilation and the lead-in's first frame."""
    ms_per_frame: float
    """Wall milliseconds per clip frame (all its solver steps and checks)."""
    wall_s: float
    retried_frames: tuple = ()
    """Clip frames (negative: lead-in chunks) that blew up once and were re-run finer."""
    refined_frames: tuple = ()
    """Clip frames (negative: lead-in chunks) re-run finer, not blown up, because a limb went
    through the cloth within one step (``SimConfig.retry_depth``)."""
    strain_max: float = 0.0
    """Largest edge stretch (l - l0) / l0 over all edges and frames (what the fabric limits)."""
    strain_mean: float = 0.0
    """Mean stretch (compressed edges count as 0)."""
    strain_p99: float = 0.0
    """99th percentile of the stretch over edges and frames."""
    strain_over_limit: float = 0.0
    """Fraction of edge-frames stretched beyond the fabric's limit."""
    strain_limit: float = 0.0
    """The fabric's ``max_strain``."""
    compression_max: float = 0.0
    """Largest edge compression (l0 - l) / l0: cloth bunching where a coarse mesh cannot fold
    (not a blow-up; reported so it can be watched)."""
    penetration_mean_mm: float = 0.0
    """Mean over all free (unpinned) vertices and frames of the depth inside the body colliders
    (0 outside)."""
    penetration_p99_mm: float = 0.0
    penetration_max_mm: float = 0.0
    penetrating_fraction: float = 0.0
    """Fraction of free vertex-frames inside the colliders."""
    hem_radius_ratio: float | None = None
    """This and the five below: :class:`core.sim.sanity.BandMeasures`, the waistband and the
    hem against the body (the hem's radius over the garment's as dressed)."""
    waistband_rise_max_mm: float | None = None
    hem_rise_end_mm: float | None = None
    end_tilt_deg: float | None = None
    end_hips_height: float | None = None
    end_feet_m: float | None = None
    finite: bool = True
    notes: list = field(default_factory=list)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["retried_frames"] = list(self.retried_frames)
        d["refined_frames"] = list(self.refined_frames)
        d["strain_ok"] = bool(self.strain_max <= self.strain_limit)
        return d


def edge_strain(positions: np.ndarray, edges: np.ndarray, rest_lengths: np.ndarray) -> np.ndarray:
    """Signed edge strain (l - l0) / l0: positive stretched, negative compressed.

    positions (..., V, 3), edges (E, 2), rest_lengths (E,) -> (..., E) float.
    """
    d = positions[..., edges[:, 1], :] - positions[..., edges[:, 0], :]
    return np.linalg.norm(d, axis=-1) / rest_lengths - 1.0


def mesh_penetration_depths(
    positions: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray
) -> np.ndarray:
    """Depth (metres, >= 0) of each vertex inside a closed body mesh, per frame.

    The check against the body that is rendered (the skinned mannequin), beside the one
    against the colliders the solver saw (:func:`penetration_depths`).

    Parameters
    ----------
    positions : (T, N, 3) float
    body_vertices : (T, B, 3) float, the posed body mesh at the same frames
    body_faces : (F, 3) int, closed and outward-facing

    Returns
    -------
    (T, N) float32
    """
    import open3d as o3d

    out = np.empty(positions.shape[:2], np.float32)
    faces = o3d.core.Tensor(np.asarray(body_faces, np.uint32))
    for t in range(len(positions)):
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(np.asarray(body_vertices[t], np.float32)), faces)
        sd = scene.compute_signed_distance(o3d.core.Tensor(np.asarray(positions[t], np.float32)))
        out[t] = np.maximum(-sd.numpy(), 0.0)
    return out


def _capsule_gaps(point: np.ndarray, ends: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Signed distance from one point (3,) to each capsule (K, 2, 3): (K,)."""
    return closest_on_segments(point, ends[:, 0], ends[:, 1])[0] - radii


def _capsule_frames(ends: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest frames of capsules (K, 2, 3): centres (K, 3), rotations (K, 3, 3) taking +Z to the
    axis, half-heights (K,)."""
    c = ends.mean(axis=1)
    d = ends[:, 1] - ends[:, 0]
    half = 0.5 * np.linalg.norm(d, axis=1)
    rots = np.empty((len(ends), 3, 3))
    for k, (v, h) in enumerate(zip(d, half)):
        z = v / (2 * h) if h > 1e-9 else np.array([0.0, 0.0, 1.0])
        x = np.cross([0.0, 1.0, 0.0], z)
        if np.linalg.norm(x) < 1e-6:
            x = np.cross([1.0, 0.0, 0.0], z)
        x /= np.linalg.norm(x)
        rots[k] = np.stack([x, np.cross(z, x), z], axis=1)
    return c, rots, half


def _interp_transforms(ma: np.ndarray, mb: np.ndarray, w: float) -> np.ndarray:
    """Rigid transforms (J, 4, 4) between ``ma`` and ``mb``: slerped rotation, lerped offset."""
    from scipy.spatial.transform import Rotation

    ra = Rotation.from_matrix(ma[:, :3, :3].astype(np.float64))
    rb = Rotation.from_matrix(mb[:, :3, :3].astype(np.float64))
    r = ra * Rotation.from_rotvec((ra.inv() * rb).as_rotvec() * w)
    out = np.zeros_like(ma, dtype=np.float64)
    out[:, :3, :3] = r.as_matrix()
    out[:, :3, 3] = (1 - w) * ma[:, :3, 3] + w * mb[:, :3, 3]
    out[:, 3, 3] = 1.0
    return out


class _Scene:
    """The newton model, solver and states of one simulation (internal)."""

    def __init__(
        self,
        garment: Mesh,
        config: SimConfig,
        capsules,
        pins,
        seams: Seams,
        m0: np.ndarray,
        thickness: np.ndarray | None = None,
    ):
        import warp as wp

        # Before newton initialises warp: no banner, and no per-module load lines.
        wp.config.quiet = True
        wp.config.log_level = wp.LOG_WARNING
        import newton

        self.wp = wp
        self.config = config
        fab = config.material
        if thickness is not None:  # the envelope meets the body through its sliding layers
            fab = replace(fab, friction=config.layer_friction)
        self.device = wp.get_device(config.device)
        self.caps_c, self.caps_r, half = _capsule_frames(capsules.endpoints.astype(np.float64))
        self.caps_joint = capsules.joints
        b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -9.81, 0.0))
        cfg = b.default_shape_cfg.copy()
        cfg.ke = config.contact_ke
        cfg.kd = 1.0e-2
        cfg.mu = fab.friction
        cfg.has_shape_collision = False  # capsules are kinematic: no body-body contacts
        # Arms (when they collide at all) slide on cloth without friction: a hand swept behind
        # the back pinched the skirt against the hips on the default dance.
        arm_cfg = cfg.copy()
        arm_cfg.mu = 0.0
        poses = self._body_poses(m0)
        for k in range(capsules.count):
            body = b.add_body(xform=wp.transform(*poses[k]), is_kinematic=True, mass=0.0)
            shape_cfg = arm_cfg if is_arm(capsules.names[k]) else cfg
            b.add_shape_capsule(
                body, radius=float(capsules.radii[k]), half_height=float(half[k]), cfg=shape_cfg
            )
        self.first_particle = b.particle_count
        if config.solver == "style3d":
            self._add_style3d_cloth(b, garment, fab)
        else:
            b.add_cloth_mesh(
                pos=wp.vec3(0.0, 0.0, 0.0),
                rot=wp.quat_identity(),
                scale=1.0,
                vel=wp.vec3(0.0, 0.0, 0.0),
                vertices=[wp.vec3(*p) for p in garment.vertices.tolist()],
                indices=garment.faces.reshape(-1).tolist(),
                density=fab.density,
                tri_ke=fab.stretch_ke,
                tri_ka=fab.stretch_ke,
                tri_kd=fab.stretch_kd,
                edge_ke=fab.bend_ke,
                edge_kd=fab.bend_kd,
                particle_radius=config.collision_margin,
            )
        # Kinematic particles (pinned, sewn): zero mass, newton then leaves them out of the solve.
        for i in np.concatenate([pins.indices, seams.indices]):
            b.particle_mass[self.first_particle + int(i)] = 0.0
        if config.solver == "vbd":
            b.color(include_bending=True)
        self.model = m = b.finalize(device=self.device)
        if thickness is not None:  # each vertex kept off the body by the layers beneath it
            radius = m.particle_radius.numpy()
            radius[self.first_particle :] += thickness.astype(np.float32)
            m.particle_radius = wp.array(radius, dtype=wp.float32, device=self.device)
            m.particle_max_radius = float(radius.max())
        m.soft_contact_ke = config.contact_ke
        m.soft_contact_kd = 1.0e-2
        m.soft_contact_mu = fab.friction
        if config.solver == "style3d":
            with contextlib.redirect_stdout(sys.stderr):  # it prints its precompute time
                self.solver = newton.solvers.SolverStyle3D(
                    model=m,
                    config=newton.solvers.SolverStyle3D.Config(iterations=config.iterations),
                )
            self.solver.config.linear_iterations = config.linear_iterations
            launch = wp.launch
            if not self.device.is_cuda:
                self.launcher = _RecordedLaunches(wp)  # the serial PCG's and our step's
                self._serial_pcg()
                _record_style3d_launches(wp)
                launch = self.launcher.launch
            from core.sim.style3d import AcceleratedStep  # imports warp and newton: deferred

            self.style3d_step = AcceleratedStep(self.solver, config.chebyshev_rho, launch)
            col = self.solver.collision
            # Style3D keeps twice this radius between cloth pieces (its "thickness").
            col.radius = 0.5 * config.self_contact_thickness
            if not config.self_collision:  # body contacts stay; cloth-cloth terms off
                col.stiff_vf = col.stiff_ee = col.stiff_ef = 0.0
            else:
                self._guard_pinned_contacts()
        else:
            kwargs = {}
            if self.device.is_cuda:
                kwargs["deterministic"] = wp.config.DeterministicMode.RUN_TO_RUN
            if config.self_collision:
                kwargs.update(
                    particle_self_contact_margin=config.collision_margin,
                    particle_self_contact_gap=config.collision_margin,
                )
            self.solver = newton.solvers.SolverVBD(
                m,
                iterations=config.iterations,
                integrate_with_external_rigid_solver=True,
                particle_enable_self_contact=config.self_collision,
                **kwargs,
            )
        self.pipeline = newton.CollisionPipeline(m, soft_contact_gap=config.contact_gap)
        self.contacts = self.pipeline.contacts()
        self.s0, self.s1 = m.state(), m.state()
        self.control = m.control()
        if config.solver == "style3d":
            self.solver.rebuild_bvh(self.s0)
        self.pin_idx = wp.array(
            (pins.indices + self.first_particle).astype(np.int32),
            dtype=wp.int32,
            device=self.device,
        )
        self.pins = pins
        self.seams = seams
        first, dev = self.first_particle, self.device
        self.sewn = (
            wp.array((seams.indices + first).astype(np.int32), dtype=wp.int32, device=dev),
            wp.array((seams.hosts + first).astype(np.int32), dtype=wp.vec3i, device=dev),
            wp.array(seams.barycentric, dtype=wp.vec3, device=dev),
            wp.array(seams.normal_offset, dtype=wp.float32, device=dev),
            wp.array(seams.residual, dtype=wp.vec3, device=dev),
        )
        self.faces = wp.array((garment.faces + first).astype(np.int32), dtype=wp.vec3i, device=dev)
        self.normals = wp.zeros(self.model.particle_count, dtype=wp.vec3, device=dev)
        self.n = garment.num_vertices

    def _serial_pcg(self) -> None:
        """Run each of Style3D's linear solves as one launch of :func:`pcg_serial`.

        Newton's PCG launches five kernels per iteration; on a CPU each launch costs tens of
        microseconds of Python and argument packing, more than the arithmetic on a few thousand
        particles, and ``linear_iterations`` of them run per solver iteration. The ELL matrix is
        constant (built once from the rest shape); it is unpacked here once.
        """
        from core.sim._kernels import pcg_serial  # imports warp: deferred

        wp, dev, solver = self.wp, self.device, self.solver
        n = self.model.particle_count
        ell = solver.pd_non_diags.nz_ell.numpy()
        column = wp.array(np.ascontiguousarray(ell["column_index"]), dtype=wp.int32, device=dev)
        value = wp.array(np.ascontiguousarray(ell["value"]), dtype=wp.float32, device=dev)
        num_nz = solver.pd_non_diags.num_nz
        scratch = [wp.zeros(n, dtype=wp.vec3, device=dev) for _ in range(4)]
        no_contacts = wp.zeros(n, dtype=wp.mat33, device=dev)
        col = solver.collision

        launcher = self.launcher

        def solve(a_non_diag, a_diag, x0, b, inv_m, x1, iterations, additional=None):
            if x0 is not None and x0.ptr != x1.ptr:
                x1.assign(x0)
            h = no_contacts if additional is None else col.contact_hessian_diagonal()
            launcher.launch(
                pcg_serial,
                dim=1,
                inputs=[n, int(iterations), int(x0 is not None), num_nz, column, value, a_diag,
                        h, b, inv_m, x1, *scratch],
                device=dev,
            )  # fmt: skip

        solver.linear_solver.solve = solve

    def _guard_pinned_contacts(self) -> None:
        """Make Style3D's cloth-cloth contacts among kinematic particles finite (and nil).

        Style3D weighs a vertex-face (or edge-edge) contact by the harmonic mean ``a * b / (a +
        b)`` of the particles' rows of the system diagonal, and that row is 0 for a kinematic
        (zero-mass: pinned or sewn) particle. A contact whose every particle is kinematic is
        weighed 0 / 0: a NaN force that the global PCG solve spreads to every particle in the
        first step. Stacked parts pinned at one waist (a layered skirt's tiers and waistband,
        4 mm apart, within the contact thickness) do exactly that. Here the weights get a tiny
        floor: such contacts weigh ~0 instead of NaN, and a contact of a kinematic particle with
        free cloth stays as newton makes it (~0: kinematic cloth does not push cloth; a sewn
        seam pushing the very part it follows would push itself away without end).
        """
        from core.sim._kernels import contact_stiffness  # imports warp: deferred

        wp, dev, solver = self.wp, self.device, self.solver
        col = solver.collision
        safe = wp.zeros(self.model.particle_count, dtype=wp.float32, device=dev)
        accumulate = col.accumulate_contact_force

        def accumulate_contact_force(dt, _iter, state_in, state_out, contacts, forces, q_prev,
                                     particle_stiff=None):  # fmt: skip
            if particle_stiff is not None:
                wp.launch(
                    contact_stiffness,
                    dim=safe.shape[0],
                    inputs=[particle_stiff, KINEMATIC_CONTACT_WEIGHT],
                    outputs=[safe],
                    device=dev,
                )
                particle_stiff = safe
            accumulate(dt, _iter, state_in, state_out, contacts, forces, q_prev, particle_stiff)

        col.accumulate_contact_force = accumulate_contact_force

    def _add_style3d_cloth(self, b, garment: Mesh, fab) -> None:
        """Style3D cloth: rest shape from per-triangle flat panels (each triangle laid out in
        its own plane, so the rest lengths and areas are exactly the mesh's)."""
        import warp as wp
        from newton.solvers import SolverStyle3D, style3d

        SolverStyle3D.register_custom_attributes(b)
        v = garment.vertices.astype(np.float64)
        f = garment.faces
        a, e1, e2 = v[f[:, 0]], v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
        l1 = np.linalg.norm(e1, axis=1)
        x = e1 / l1[:, None]
        n = np.cross(e1, e2)
        n /= np.linalg.norm(n, axis=1)[:, None]
        y = np.cross(n, x)
        panel = np.zeros((len(f), 3, 2))
        panel[:, 1, 0] = l1
        panel[:, 2, 0] = (e2 * x).sum(1)
        panel[:, 2, 1] = (e2 * y).sum(1)
        del a
        ke, kb = fab.stretch_ke, fab.bend_ke
        style3d.add_cloth_mesh(
            b,
            pos=wp.vec3(0.0, 0.0, 0.0),
            rot=wp.quat_identity(),
            vel=wp.vec3(0.0, 0.0, 0.0),
            vertices=v.tolist(),
            indices=f.reshape(-1).tolist(),
            panel_verts=panel.reshape(-1, 2).tolist(),
            panel_indices=list(range(3 * len(f))),
            density=fab.density,
            tri_aniso_ke=wp.vec3(ke, ke, 0.5 * ke),
            edge_aniso_ke=wp.vec3(kb, kb, kb),
            tri_kd=fab.stretch_kd,
            edge_kd=fab.bend_kd,
            particle_radius=self.config.collision_margin,
        )

    def _body_poses(self, m: np.ndarray) -> np.ndarray:
        """Capsule body transforms [p, q xyzw] for skinning transforms m (..., J, 4, 4):
        (..., K, 7) float32 (a whole drive's steps at once, or one pose)."""
        from scipy.spatial.transform import Rotation

        mk = np.asarray(m, np.float64)[..., self.caps_joint, :, :]
        rot = mk[..., :3, :3] @ self.caps_r
        pos = np.einsum("...kab,kb->...ka", mk[..., :3, :3], self.caps_c) + mk[..., :3, 3]
        quat = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_quat().reshape(rot.shape[:-2] + (4,))
        return np.concatenate([pos, quat], axis=-1).astype(np.float32)

    def _body_vel(self, pa: np.ndarray, pb: np.ndarray, dt: float) -> np.ndarray:
        """Spatial velocities (..., K, 6) [linear, angular] taking poses pa to pb (..., K, 7)."""
        from scipy.spatial.transform import Rotation

        lin = (pb[..., :3] - pa[..., :3]) / dt
        qa, qb = pa[..., 3:].reshape(-1, 4), pb[..., 3:].reshape(-1, 4)
        ang = (Rotation.from_quat(qb) * Rotation.from_quat(qa).inv()).as_rotvec() / dt
        return np.concatenate([lin, ang.reshape(lin.shape)], axis=-1).astype(np.float32)

    def step(self, ma: np.ndarray, mb: np.ndarray, dt: float, poses: tuple | None = None) -> None:
        """One solver step with the body moving from transforms ``ma`` to ``mb`` (J, 4, 4).

        ``poses``: the capsules' (pa, pb, velocity) for them when already computed (a whole
        drive's at once, :meth:`_body_poses` and :meth:`_body_vel` on all its steps)."""
        from core.sim._kernels import scale_velocities, set_pinned  # imports warp: deferred

        wp = self.wp
        if poses is None:
            pa, pb = self._body_poses(ma), self._body_poses(mb)
            vel = self._body_vel(pa, pb, dt)
        else:
            pa, pb, vel = poses
        dev = self.device
        self.s0.body_q.assign(wp.array(pa, dtype=wp.transform, device=dev))
        self.s0.body_qd.assign(wp.array(vel, dtype=wp.spatial_vector, device=dev))
        self.s1.body_q.assign(wp.array(pb, dtype=wp.transform, device=dev))
        self.s1.body_qd.assign(wp.array(vel, dtype=wp.spatial_vector, device=dev))
        if len(self.pins.indices):
            targets = wp.array(self.pins.targets(mb), dtype=wp.vec3, device=dev)
            wp.launch(
                set_pinned,
                dim=len(self.pins.indices),
                inputs=[self.pin_idx, targets, self.s0.particle_q, self.s0.particle_qd],
                device=dev,
            )
        # Sewn particles are kinematic too: placed where their hosts will be at the end of the
        # step (moved on at their velocities; left where the hosts are, they would drag one step
        # behind, stretching the seam by the host's speed times dt), then put back exactly.
        self._sew(dt)
        self.s0.clear_forces()
        self.pipeline.collide(self.s0, self.contacts)
        if self.config.solver == "style3d":
            self.style3d_step(self.s0, self.s1, self.contacts, dt)
        else:
            self.solver.step(self.s0, self.s1, self.control, self.contacts, dt)
        self.s0, self.s1 = self.s1, self.s0
        factor = float(np.exp(-self.config.damping * dt))
        if self.config.solver == "style3d":
            factor /= STYLE3D_VELOCITY_FACTOR
        if factor != 1.0:
            wp.launch(
                scale_velocities,
                dim=self.n,
                inputs=[self.first_particle, factor, self.s0.particle_qd],
                device=dev,
            )
        self._sew(0.0)

    def _sew(self, ahead: float) -> None:
        from core.sim._kernels import accumulate_normals, set_sewn  # imports warp: deferred

        if not len(self.seams.indices):
            return
        wp, q, qd = self.wp, self.s0.particle_q, self.s0.particle_qd
        self.normals.zero_()
        wp.launch(
            accumulate_normals,
            dim=self.faces.shape[0],
            inputs=[self.faces, ahead, q, qd, self.normals],
            device=self.device,
        )
        wp.launch(
            set_sewn,
            dim=len(self.seams.indices),
            inputs=[*self.sewn, self.normals, ahead, q, qd],
            device=self.device,
        )

    def positions(self) -> np.ndarray:
        q = self.s0.particle_q.numpy()
        return np.array(q[self.first_particle : self.first_particle + self.n], np.float32)

    def velocities(self) -> np.ndarray:
        qd = self.s0.particle_qd.numpy()
        return np.array(qd[self.first_particle : self.first_particle + self.n], np.float32)

    def snapshot(self) -> tuple[np.ndarray, np.ndarray]:
        return self.s0.particle_q.numpy().copy(), self.s0.particle_qd.numpy().copy()

    def restore(self, snap: tuple[np.ndarray, np.ndarray]) -> None:
        wp = self.wp
        self.s0.particle_q.assign(wp.array(snap[0], dtype=wp.vec3, device=self.device))
        self.s0.particle_qd.assign(wp.array(snap[1], dtype=wp.vec3, device=self.device))


@dataclass
class Prepared:
    """A simulation set up and not yet stepped (:func:`prepare`): the scene at the rest pose and
    the body's poses and velocities at every solver step of the lead-in and the clip."""

    scene: _Scene | ImplicitScene
    drive: BodyDrive
    poses: np.ndarray
    """(S + 1, K, 7) float32: the capsules' transforms at every step boundary (the implicit
    solver's: (S + 1, K, 2, 3), their segments)."""
    velocities: np.ndarray
    """(S, K, 6) float32: the capsules' spatial velocities over every step ((S, 0) for the
    implicit solver, which takes them from the poses)."""
    config: SimConfig
    """The config as run: ``self_collision`` and ``chebyshev_rho`` resolved."""
    capsules: BodyCapsules
    """The colliders the cloth meets (the arms only when they collide)."""
    pins: Pins
    seams: Seams
    edges: np.ndarray
    """(E, 2) int: the garment's unique edges."""
    rest_lengths: np.ndarray
    """(E,) float64: their rest lengths."""
    notes: list
    thickness: np.ndarray | None = None
    """(V,) float64 metres each vertex is kept off the body beyond the margin, or None."""

    def step(self, a: int, b: int) -> None:
        """Solver steps ``a``..``b`` of the drive, as :func:`simulate` runs them (no checks)."""
        for s in range(a, b):
            self.scene.step(
                self.drive.transforms[s], self.drive.transforms[s + 1], self.drive.dt,
                (self.poses[s], self.poses[s + 1], self.velocities[s]),
            )  # fmt: skip


def prepare(
    garment: Mesh,
    motion,
    shape: BodyShape,
    config: SimConfig | None = None,
    path=None,
    thickness: np.ndarray | None = None,
) -> Prepared:
    """Build the scene of ``garment`` under ``motion`` (the setup of :func:`simulate`, whose
    arguments these are): the body drive, colliders, pins, seams, the solver and every step's
    capsule poses. ``InputError`` for a motion not on the mannequin, a garment with nothing to
    pin, a zero-length edge or a ``thickness`` not (V,) finite and >= 0."""
    config = SimConfig() if config is None else config
    skeleton = mannequin_skeleton(shape)
    rotations, roots = motion_arrays(skeleton, motion, path)
    n = config.steps_per_frame(motion.fps)
    drive = body_drive(
        skeleton, rotations, roots, motion.fps, n, config.transition_s, config.settle_s
    )
    top = float(garment.vertices[:, 1].max())
    capsules = garment_capsules(skeleton, shape, top, config.arm_colliders)
    notes: list[str] = []
    if not arms_collide(shape, top, config.arm_colliders):
        notes.append("arms do not collide with this garment (it stays below the chest)")
    pins = find_pins(
        garment.vertices, garment.faces, skeleton, config.pin_distance, shape.height, path
    )
    seams = find_seams(garment.vertices, garment.faces, pins.indices, config.pin_distance)
    if seams.pieces:
        notes.append(
            f"{seams.pieces} loose piece(s) (no pinned vertex) sewn by {len(seams.indices)} "
            "vertices to the parts beside them"
        )
    if seams.loose:
        notes.append(f"{seams.loose} loose piece(s) with no part within reach: left free")
    edges = unique_edges(garment.faces)
    rest_len = np.linalg.norm(
        garment.vertices[edges[:, 1]].astype(np.float64) - garment.vertices[edges[:, 0]], axis=1
    )
    if (rest_len <= 0).any():
        raise InputError("garment has zero-length edges", path)
    if config.self_collision is None:
        layered = count_components(garment.num_vertices, garment.faces) > 1
        config = replace(config, self_collision=layered)
        notes.append(
            f"self-collision {'on: the garment has several pieces' if layered else 'off: one surface'}"
        )
    if config.chebyshev_rho is None:
        rho = 0.0 if config.self_collision else CHEBYSHEV_RHO
        config = replace(config, chebyshev_rho=rho)
    if thickness is not None:
        thickness = contact_thickness(garment, capsules, config, thickness, path)
        notes.append(
            f"kept off the body by the layers beneath it: up to {1e3 * thickness.max():.0f} mm "
            f"(mean {1e3 * thickness.mean():.0f}) beyond the {1e3 * config.collision_margin:.0f} "
            f"mm margin, at friction {config.layer_friction:g}"
            + (f", soft at {config.layer_ke:g} N/m" if config.solver == "implicit" else "")
        )
    if config.solver == "implicit":
        from core.sim.implicit import ImplicitScene  # scipy only: no warp, no newton

        scene = ImplicitScene(
            garment, config, capsules, pins, seams, drive.transforms[0], thickness
        )
        poses = scene.body_poses(drive.transforms)  # every step's capsule segments at once
        velocities = np.zeros((len(poses) - 1, 0), np.float32)  # it takes them from the poses
    else:
        scene = _Scene(garment, config, capsules, pins, seams, drive.transforms[0], thickness)
        poses = scene._body_poses(drive.transforms)  # every step's capsule poses at once
        velocities = scene._body_vel(poses[:-1], poses[1:], drive.dt)
    return Prepared(
        scene, drive, poses, velocities, config, capsules, pins, seams, edges, rest_len, notes,
        thickness,
    )  # fmt: skip


def contact_thickness(
    garment: Mesh, capsules: BodyCapsules, config: SimConfig, thickness: np.ndarray, path=None
) -> np.ndarray:
    """``thickness`` (V,) metres (:func:`core.sim.thickness.layer_thickness`), each vertex's
    capped at its room from the body at rest beyond ``config.collision_margin``, so the rest
    drape does not start inside its own shell: (V,) float64 >= 0."""
    t = np.asarray(thickness, np.float64)
    if t.shape != (garment.num_vertices,) or not np.isfinite(t).all() or (t < 0).any():
        raise InputError(
            f"thickness must be (V,) = ({garment.num_vertices},) finite metres >= 0, got shape "
            f"{t.shape}",
            path,
        )
    room = capsule_distance(
        garment.vertices.astype(np.float64), capsules.endpoints.astype(np.float64), capsules.radii
    )
    return np.clip(np.minimum(t, room - config.collision_margin), 0.0, None)


def simulate(
    garment: Mesh,
    motion,
    shape: BodyShape | None = None,
    config: SimConfig | None = None,
    *,
    path=None,
    progress: Callable[[int, int], None] | None = None,
    thickness: np.ndarray | None = None,
) -> tuple[SimCache, SimReport]:
    """Simulate ``garment`` (in its rest pose on the rest mannequin) under ``motion``.

    Parameters
    ----------
    garment : Mesh, vertices (V, 3) float32 in the rest (A-pose) frame of ``shape``'s mannequin
    motion : core.motion.Motion on the mannequin's joints (``MANNEQUIN_JOINTS``), T frames
    shape : the body (default ``BodyShape()``)
    config : SimConfig (default ``SimConfig()``)
    path : the garment's file, named in errors
    progress : called with (frames done, total) after every kept clip frame
    thickness : (V,) float metres or None, the depth of a layered garment's layers beneath each
        vertex of its proxy (:mod:`core.sim.thickness`): added to the vertex's contact margin,
        up to its room from the body at rest

    Returns
    -------
    cache : SimCache, positions (T, V, 3) float32, frame 0 after the lead-in
    report : SimReport

    Raises
    ------
    SimulationError
        A frame blew up (non-finite, runaway speed, strain far beyond the fabric's) and stayed
        blown up after ``config.max_retries`` finer retries.
    InputError
        Motion not on the mannequin; garment with no boundary to pin.
    """
    t_start = time.perf_counter()
    shape = BodyShape() if shape is None else shape
    run = prepare(garment, motion, shape, config, path, thickness)
    scene, drive, config = run.scene, run.drive, run.config
    capsules, pins, seams = run.capsules, run.pins, run.seams
    edges, rest_len, notes, n = run.edges, run.rest_lengths, run.notes, drive.steps_per_frame
    fab = config.material
    strain_blowup = config.blowup_strain * fab.max_strain

    def check(q: np.ndarray, qd: np.ndarray, step: int) -> str | None:
        if not (np.isfinite(q).all() and np.isfinite(qd).all()):
            return "non-finite positions"
        speed = float(np.linalg.norm(qd, axis=1).max())
        if speed > config.max_speed:
            return f"runaway speed {speed:.1f} m/s (limit {config.max_speed})"
        strain = edge_strain(q, edges, rest_len)  # stretch only: compression is bounded
        if strain.max() > strain_blowup:
            e = int(strain.argmax())
            mid = 0.5 * (q[edges[e, 0]] + q[edges[e, 1]])
            ends = pose_capsules(capsules, drive.transforms[step][None])[0]
            near = capsules.names[int(_capsule_gaps(mid, ends, capsules.radii).argmin())]
            return (
                f"edge strain {strain.max():.2f} (fabric {fab.name} allows {fab.max_strain}, "
                f"blow-up at {strain_blowup:.2f}) at vertices {edges[e].tolist()}, "
                f"height {mid[1]:.2f} m, near the {near} collider"
            )
        return None

    free = np.setdiff1d(np.arange(garment.num_vertices), pins.indices)

    def depth(q: np.ndarray, step: int) -> float:
        """The deepest free vertex inside the body's capsules at drive step ``step`` (metres)."""
        ends = pose_capsules(capsules, drive.transforms[step][None])[0]
        return float(penetration_depths(q[None, free], ends[None], capsules.radii).max(initial=0))

    def run_chunk(a: int, b: int, label: int) -> tuple[bool, bool]:
        """Steps a..b of the drive; retries finer on blow-up, or where a limb went through the
        cloth (``config.retry_depth``). Whether it was retried for each of the two."""
        snap = scene.snapshot()
        blew = deep = False
        limit = config.retry_depth
        if limit is not None:
            limit = max(limit, depth(scene.positions(), a))
        for attempt in range(config.max_retries + 1):
            split = 2**attempt
            if split == 1:
                run.step(a, b)
            else:
                for s in range(a, b):
                    ma, mb = drive.transforms[s], drive.transforms[s + 1]
                    for k in range(split):
                        m0 = _interp_transforms(ma, mb, k / split)
                        m1 = _interp_transforms(ma, mb, (k + 1) / split)
                        scene.step(m0, m1, drive.dt / split)
            problem = check(scene.positions(), scene.velocities(), b)
            if problem is None:
                finer = attempt < config.max_retries and limit is not None
                if not (finer and depth(scene.positions(), b) > limit):
                    return blew, deep
                deep = True
            else:
                blew = True
            if attempt < config.max_retries:
                scene.restore(snap)
        where = f"clip frame {label}" if label >= 0 else "the lead-in from the rest pose"
        raise SimulationError(
            f"simulation blew up at {where}: {problem}, still after {config.max_retries} "
            f"retries with up to {2**config.max_retries}x the steps; try more --substeps, "
            "more iterations, a stiffer fabric or a slower clip",
            path,
            frame=label,
            positions=scene.positions(),
        )

    retried: list[int] = []
    refined: list[int] = []

    def chunk(a: int, b: int, label: int) -> None:
        blew, deep = run_chunk(a, b, label)
        if blew:
            retried.append(label)
        elif deep:
            refined.append(label)

    frames: list[np.ndarray] = []
    # Lead-in, in chunks of one frame's steps.
    chunk_ends = list(range(n, drive.preroll_steps, n)) + [drive.preroll_steps]
    a = 0
    setup_s = None
    for i, b in enumerate(chunk_ends):
        if b > a:
            chunk(a, b, -1 - i)
        if setup_s is None:
            setup_s = time.perf_counter() - t_start
        a = b
    frames.append(scene.positions())
    t_clip = time.perf_counter()
    if setup_s is None:
        setup_s = t_clip - t_start
    if progress:
        progress(1, drive.num_frames)
    for f in range(1, drive.num_frames):
        a, b = drive.frame_step(f - 1), drive.frame_step(f)
        chunk(a, b, f)
        frames.append(scene.positions())
        if progress:
            progress(f + 1, drive.num_frames)
    clip_s = time.perf_counter() - t_clip
    positions = np.stack(frames).astype(np.float32)
    report = _report(
        positions, garment, drive, capsules, pins, free, edges, rest_len, config, retried,
        refined, setup_s, clip_s, time.perf_counter() - t_start, str(scene.device), notes,
        _pelvis(mannequin_skeleton(shape), drive),
    )  # fmt: skip
    params = {
        "sim": config.as_dict(),
        "body_shape": shape.as_dict(),
        "motion": {"name": motion.name, "frames": motion.num_frames, "fps": motion.fps},
        "garment": {"path": None if path is None else str(path), "vertices": garment.num_vertices},
        "steps_per_frame": n,
        "pinned_vertices": int(len(pins.indices)),
        "pinned_indices": pins.indices.tolist(),
        "sewn_vertices": int(len(seams.indices)),
        "colliders": list(capsules.names),
        "layer_thickness_mm": None
        if run.thickness is None
        else {"mean": 1e3 * float(run.thickness.mean()), "max": 1e3 * float(run.thickness.max())},
        "solver": SOLVER_CLASSES[config.solver],
        "newton_version": _newton_version(),
    }
    return SimCache(positions, garment.faces.astype(np.int64), float(motion.fps), params), report


def _newton_version() -> str:
    """newton's installed version, read from its metadata: importing newton (5 s) only to
    name it would cost the implicit solver, which does not use it, that much per process."""
    try:
        return version("newton")
    except PackageNotFoundError:
        return "unknown"


def _pelvis(skeleton, drive: BodyDrive) -> Pelvis:
    """The :class:`~core.sim.sanity.Pelvis` of ``skeleton`` at every clip frame of ``drive``."""
    rest = skeleton.rest_positions().astype(np.float64)
    joints = [skeleton.names.index(n) for n in PELVIS_JOINTS]
    m = drive.transforms[[drive.frame_step(f) for f in range(drive.num_frames)]]
    m = m[:, joints].astype(np.float64)  # (T, 4, 4, 4)
    at = np.einsum("tjab,jb->tja", m[..., :3, :3], rest[joints]) + m[..., :3, 3]
    return Pelvis.of(at, rest[joints])


def _report(
    positions, garment, drive: BodyDrive, capsules, pins, free, edges, rest_len,
    config: SimConfig, retried, refined, setup_s, clip_s, wall_s, device, notes, pelvis,
) -> SimReport:  # fmt: skip
    t = len(positions)
    strain = edge_strain(positions, edges, rest_len)
    ends = pose_capsules(capsules, drive.transforms[[drive.frame_step(f) for f in range(t)]])
    depth = penetration_depths(positions[:, free], ends, capsules.radii)
    bands = band_measures(
        positions, garment.vertices, garment.faces, pins.indices, pelvis,
        end_frames=max(1, int(round(0.5 / (drive.dt * drive.steps_per_frame)))),
    )  # fmt: skip
    return SimReport(
        frames=t,
        vertices=garment.num_vertices,
        pinned=int(len(pins.indices)),
        steps_per_frame=drive.steps_per_frame,
        preroll_steps=drive.preroll_steps,
        device=device,
        setup_s=round(setup_s, 3),
        ms_per_frame=round(1000.0 * clip_s / max(t - 1, 1), 2),
        wall_s=round(wall_s, 3),
        retried_frames=tuple(retried),
        refined_frames=tuple(refined),
        strain_max=float(max(strain.max(), 0.0)),
        strain_mean=float(np.maximum(strain, 0.0).mean()),
        strain_p99=float(max(np.percentile(strain, 99), 0.0)),
        strain_over_limit=float((strain > config.material.max_strain).mean()),
        strain_limit=config.material.max_strain,
        compression_max=float(max(-strain.min(), 0.0)),
        penetration_mean_mm=float(depth.mean() * 1000),
        penetration_p99_mm=float(np.percentile(depth, 99) * 1000) if depth.size else 0.0,
        penetration_max_mm=float(depth.max() * 1000) if depth.size else 0.0,
        penetrating_fraction=float((depth > 0).mean()) if depth.size else 0.0,
        **asdict(bands),
        finite=bool(np.isfinite(positions).all()),
        notes=list(notes),
    )
