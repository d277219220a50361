"""One Style3D step with Chebyshev-accelerated iterations (imported only when a simulation runs).

newton's Style3D solver is projective dynamics: every step runs ``iterations`` local-global
iterations (forces at the current iterate, one PCG solve with the constant projective-dynamics
matrix, a move). Such iterations remove high-frequency error fast and smooth, large-scale error
slowly, and what is left unconverged acts like drag: on the quick project's 989-vertex proxy
under the procedural twirl the hem closes in to 0.57x its standing radius at 8 x 16 (substeps x
iterations a frame), 0.68x at 8 x 32, 0.84x at 16 x 32 and 0.93x at 32 x 32 (ratio of the mean
hem radius over the second half of the clip to frame 0's, :func:`core.sim.sanity.hem_radius_ratio`):
the answer moves with every doubling of the iterations.

Here the same iterations are combined by the Chebyshev semi-iterative method (Wang, "A Chebyshev
Semi-Iterative Approach for Accelerating Projective and Position-based Dynamics", SIGGRAPH Asia
2015): after the plain iterate ``x^`` of iteration ``k``,
``x_{k+1} = omega_{k+1} (x^ - x_{k-1}) + x_{k-1}`` with ``omega`` from the spectral radius
``rho`` of the plain iteration (:attr:`core.sim.config.SimConfig.chebyshev_rho`)::

    omega = 1 before and at iteration ``delay``, 2 / (2 - rho^2) at the next,
    then omega = 4 / (4 - rho^2 omega)

One more kernel per iteration (a few microseconds), no more solves. Everything else is newton's
step as it ships (its own kernels, in its order): with ``rho = 0`` this is newton's step, bit
for bit (``tests/test_sim_run.py``), its velocity update (0.998 of the displacement over
``dt``) included: the scene divides that factor out (``core.sim.simulate.
STYLE3D_VELOCITY_FACTOR``).
"""

from __future__ import annotations

import warp as wp
from newton._src.solvers.style3d.kernels import (
    deactivate_zero_mass_particles_kernel,
    eval_bend_kernel,
    eval_stretch_kernel,
    init_rhs_kernel,
    init_step_kernel,
    nonlinear_step_kernel,
    prepare_jacobi_preconditioner_kernel,
    update_velocity,
)

#: Plain iterations before the acceleration starts (Wang 2015 delays it a few iterations: the
#: first ones change the iterate most, and extrapolating them overshoots).
CHEBYSHEV_DELAY = 2


@wp.kernel
def chebyshev_update(
    omega: float,
    x_hat: wp.array(dtype=wp.vec3),
    x_before: wp.array(dtype=wp.vec3),
    x_now: wp.array(dtype=wp.vec3),
):
    """``x_hat <- omega (x_hat - x_before) + x_before``, then ``x_before <- x_now`` (the iterate
    the plain iteration started from, which the next update extrapolates from)."""
    i = wp.tid()
    accelerated = omega * (x_hat[i] - x_before[i]) + x_before[i]
    x_before[i] = x_now[i]
    x_hat[i] = accelerated


def chebyshev_omegas(rho: float, iterations: int, delay: int = CHEBYSHEV_DELAY) -> list[float]:
    """The weight ``omega`` of each iteration (1: the plain iterate kept)."""
    out, omega = [], 1.0
    for k in range(iterations):
        if k <= delay or rho <= 0:
            omega = 1.0
        elif k == delay + 1:
            omega = 2.0 / (2.0 - rho * rho)
        else:
            omega = 4.0 / (4.0 - rho * rho * omega)
        out.append(omega)
    return out


class AcceleratedStep:
    """Style3D steps of one ``newton.solvers.SolverStyle3D`` with Chebyshev-combined iterations.

    ``launch`` is ``wp.launch`` or a recording launcher with its signature (on a CPU the
    simulation replays recorded launches, :class:`core.sim.simulate._RecordedLaunches`).
    """

    def __init__(self, solver, rho: float, launch=wp.launch):
        if not 0.0 <= rho < 1.0:
            raise ValueError(f"chebyshev rho must be in [0, 1), got {rho}")
        self.solver = solver
        self.launch = launch
        self.omegas = chebyshev_omegas(rho, solver.config.iterations)
        self.before = wp.zeros(solver.model.particle_count, dtype=wp.vec3, device=solver.device)

    def __call__(self, state_in, state_out, contacts, dt: float) -> None:
        """One step: ``state_in``'s positions are the iterate (changed in place), the result is
        in ``state_out`` (positions and velocities)."""
        s, launch = self.solver, self.launch
        m, dev, n = s.model, s.device, s.model.particle_count
        wp.copy(s._particle_flags, m.particle_flags)
        launch(deactivate_zero_mass_particles_kernel, dim=n, inputs=[m.particle_mass],
               outputs=[s._particle_flags], device=dev)  # fmt: skip
        s.collision.frame_begin(state_in.particle_q, state_in.particle_qd, dt)
        launch(
            init_step_kernel, dim=n,
            inputs=[dt, m.gravity, m.particle_world, state_in.particle_f, state_in.particle_qd,
                    state_in.particle_q, s.x_prev, s.pd_diags, m.particle_mass, s._particle_flags],
            outputs=[s.x_inertia, s.static_A_diags, s.dx], device=dev,
        )  # fmt: skip
        q_in, q_out = state_in.particle_q, state_out.particle_q
        for k, omega in enumerate(self.omegas):
            launch(init_rhs_kernel, dim=n, inputs=[dt, q_in, s.x_inertia, m.particle_mass],
                   outputs=[s.rhs], device=dev)  # fmt: skip
            launch(
                eval_stretch_kernel, dim=len(m.tri_areas),
                inputs=[q_in, m.tri_areas, m.tri_poses, m.tri_indices, s.style3d.tri_aniso_ke],
                outputs=[s.rhs], device=dev,
            )  # fmt: skip
            launch(
                eval_bend_kernel, dim=len(s.style3d.edge_rest_area),
                inputs=[q_in, s.style3d.edge_rest_area, s.style3d.edge_bending_cot,
                        m.edge_indices, m.edge_bending_properties],
                outputs=[s.rhs], device=dev,
            )  # fmt: skip
            s.collision.accumulate_contact_force(
                dt, k, state_in, state_out, contacts, s.rhs, s.x_prev, s.static_A_diags
            )
            launch(
                prepare_jacobi_preconditioner_kernel, dim=n,
                inputs=[s.static_A_diags, s.collision.contact_hessian_diagonal(),
                        s._particle_flags],
                outputs=[s.inv_A_diags], device=dev,
            )  # fmt: skip
            s.linear_solver.solve(
                s.pd_non_diags, s.static_A_diags, s.dx if k == 0 else None, s.rhs,
                s.inv_A_diags, s.dx, s.config.linear_iterations, s.collision.hessian_multiply,
            )  # fmt: skip
            s.collision.linear_iteration_end(s.dx)
            launch(nonlinear_step_kernel, dim=n, inputs=[q_in], outputs=[q_out, s.dx], device=dev)
            if omega != 1.0:
                launch(chebyshev_update, dim=n, inputs=[float(omega), q_out, self.before, q_in],
                       device=dev)  # fmt: skip
            else:
                wp.copy(self.before, q_in)
            wp.copy(q_in, q_out)
        launch(update_velocity, dim=n, inputs=[dt, s.x_prev, q_out], outputs=[state_out.particle_qd],
               device=dev)  # fmt: skip
        s.collision.frame_end(q_out, state_out.particle_qd, dt)
