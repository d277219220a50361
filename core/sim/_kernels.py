"""Warp kernels of the simulation (imported only when a simulation runs)."""

from __future__ import annotations

import warp as wp


@wp.kernel
def set_pinned(
    indices: wp.array(dtype=wp.int32),
    targets: wp.array(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    qd: wp.array(dtype=wp.vec3),
):
    """Move pinned particles to their targets (and zero their velocity)."""
    i = wp.tid()
    q[indices[i]] = targets[i]
    qd[indices[i]] = wp.vec3(0.0, 0.0, 0.0)


@wp.kernel
def scale_velocities(first: int, factor: float, qd: wp.array(dtype=wp.vec3)):
    """Multiply the velocities of particles ``first + tid`` by ``factor``."""
    i = first + wp.tid()
    qd[i] = factor * qd[i]


@wp.kernel
def contact_stiffness(
    static_diags: wp.array(dtype=wp.float32),
    floor: float,
    out: wp.array(dtype=wp.float32),
):
    """Per-particle weights of Style3D's cloth-cloth contacts: the solver's static diagonal, at
    least ``floor`` (it is 0 for kinematic particles, and a contact among those alone would be
    weighed 0 / 0)."""
    i = wp.tid()
    out[i] = wp.max(static_diags[i], floor)


@wp.func
def _ahead(q: wp.array(dtype=wp.vec3), qd: wp.array(dtype=wp.vec3), i: int, ahead: float):
    """Where particle ``i`` will be ``ahead`` seconds on at its velocity."""
    return q[i] + ahead * qd[i]


@wp.kernel
def accumulate_normals(
    faces: wp.array(dtype=wp.vec3i),
    ahead: float,
    q: wp.array(dtype=wp.vec3),
    qd: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
):
    """Area-weighted vertex normals (unnormalised) of the positions ``ahead`` seconds on."""
    f = faces[wp.tid()]
    a = _ahead(q, qd, f[0], ahead)
    n = wp.cross(_ahead(q, qd, f[1], ahead) - a, _ahead(q, qd, f[2], ahead) - a)
    wp.atomic_add(normals, f[0], n)
    wp.atomic_add(normals, f[1], n)
    wp.atomic_add(normals, f[2], n)


@wp.kernel
def set_sewn(
    indices: wp.array(dtype=wp.int32),
    hosts: wp.array(dtype=wp.vec3i),
    barycentric: wp.array(dtype=wp.vec3),
    normal_offset: wp.array(dtype=wp.float32),
    residual: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    ahead: float,
    q: wp.array(dtype=wp.vec3),
    qd: wp.array(dtype=wp.vec3),
):
    """Move sewn particles to their host triangles (closest point, the offset along the
    interpolated vertex normal, the residual in the triangle's frame), with the velocity of that
    point; ``ahead`` seconds ahead, the host vertices moved on at their velocities (where they
    will be at the end of a step). ``normals`` from :func:`accumulate_normals` (same ahead)."""
    i = wp.tid()
    h = hosts[i]
    w = barycentric[i]
    a = _ahead(q, qd, h[0], ahead)
    b = _ahead(q, qd, h[1], ahead)
    c = _ahead(q, qd, h[2], ahead)
    e1 = wp.normalize(b - a)
    n = wp.normalize(wp.cross(b - a, c - a))
    e2 = wp.cross(n, e1)
    m = wp.normalize(w[0] * normals[h[0]] + w[1] * normals[h[1]] + w[2] * normals[h[2]])
    r = residual[i]
    x = w[0] * a + w[1] * b + w[2] * c + normal_offset[i] * m
    q[indices[i]] = x + r[0] * e1 + r[1] * e2 + r[2] * n
    qd[indices[i]] = w[0] * qd[h[0]] + w[1] * qd[h[1]] + w[2] * qd[h[2]]


@wp.kernel
def pcg_serial(
    n: int,
    iterations: int,
    warm: int,
    num_nz: wp.array(dtype=wp.int32),
    nz_column: wp.array2d(dtype=wp.int32),
    nz_value: wp.array2d(dtype=wp.float32),
    a_diag: wp.array(dtype=wp.float32),
    h_diag: wp.array(dtype=wp.mat33),
    b: wp.array(dtype=wp.vec3),
    inv_m: wp.array(dtype=wp.mat33),
    x: wp.array(dtype=wp.vec3),
    r: wp.array(dtype=wp.vec3),
    z: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=wp.vec3),
    ap: wp.array(dtype=wp.vec3),
):
    """Jacobi-preconditioned conjugate gradients for ``(A + H) x = b``, all iterations in one
    launch (launched with ``dim=1``: on a CPU, one launch per solve instead of five per
    iteration; the same arithmetic as newton's Style3D ``PcgSolver``).

    ``A`` is the projective-dynamics matrix: diagonal ``a_diag`` (n,) and off-diagonal rows in
    ELL layout (``num_nz`` (n,), ``nz_column`` / ``nz_value`` (K, n)); ``H`` the contacts'
    3x3 diagonal blocks (n,); ``inv_m`` the preconditioner's blocks. ``x`` holds the start
    when ``warm`` is 1 (zero otherwise) and the solution on return; ``r``, ``z``, ``p``,
    ``ap`` are scratch (n,)."""
    for i in range(n):
        ax = wp.vec3(0.0)
        if warm != 0:
            ax = a_diag[i] * x[i] + h_diag[i] * x[i]
            for k in range(num_nz[i]):
                ax += nz_value[k, i] * x[nz_column[k, i]]
        else:
            x[i] = wp.vec3(0.0)
        r[i] = b[i] - ax
    rz_old = wp.float32(0.0)
    for it in range(iterations):
        rz = wp.float32(0.0)
        for i in range(n):
            z[i] = inv_m[i] * r[i]
            rz += wp.dot(r[i], z[i])
        beta = wp.float32(0.0)
        if it > 0 and wp.abs(rz_old) > 1.0e-30 and not wp.isnan(rz) and not wp.isnan(rz_old):
            beta = rz / rz_old
        pap = wp.float32(0.0)
        for i in range(n):
            p[i] = z[i] + beta * p[i]
        for i in range(n):
            y = a_diag[i] * p[i] + h_diag[i] * p[i]
            for k in range(num_nz[i]):
                y += nz_value[k, i] * p[nz_column[k, i]]
            ap[i] = y
            pap += wp.dot(p[i], y)
        alpha = wp.float32(0.0)
        if wp.abs(pap) > 1.0e-30 and not wp.isnan(pap) and not wp.isnan(rz):
            alpha = rz / pap
        for i in range(n):
            x[i] = x[i] + alpha * p[i]
            r[i] = r[i] - alpha * ap[i]
        rz_old = rz
