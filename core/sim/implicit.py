"""Implicit cloth steps by Newton's method with a direct sparse solve (``solver="implicit"``).

Style3D (newton's projective dynamics) iterates with the rest shape's matrix, and near the body
its iterations converge slowly: one quick step (16 iterations) ends 9.5 mm from the same step
converged on the quick proxy's walk (docs/decisions.md, "sim_solver = implicit"). Here every step minimises
the implicit objective over the free vertices' end-of-step positions ``y``::

    E(y) = |y - x~ - h^2 g|^2_M / (2 h^2) + stretch(y) + bend(y) + contact(y) + friction(y)

with ``h = dt`` and ``x~ = x + dt v`` for backward Euler, or BDF2's (second order,
``SimConfig.implicit_order``: :meth:`ImplicitCloth.step`), by Newton's method: the exact
gradient, the Hessian made positive semi-definite term by term (the indefinite parts of
compression, shear and the contact's curvature dropped; the body contact's own in it), one
sparse LDL^T solve per iteration (qdldl on 3 x free-vertex unknowns: the matrix's pattern is
fixed, so its ordering and symbolic factorisation are made once per garment), and a backtracking
line search on ``E``. A step stops when the update (its largest vertex's, or its root mean
square: ``SimConfig.implicit_norm``) is under ``SimConfig.implicit_tol`` or after
``SimConfig.iterations`` Newton iterations.

The material is Style3D's as this project configures it (:func:`core.sim.simulate`): the
Baraff-Witkin membrane ``A (ku (|Fu| - 1)^2 + kv (|Fv| - 1)^2 + ks (Fu . Fv)^2) / 2`` on each
triangle laid flat (``ku = kv = stretch_ke``, ``ks = stretch_ke / 2``; Style3D's shear force
normalises ``Fu``, ``Fv``, the same to first order) and Bergou's quadratic (isometric) bending
``kb x^T Q x / 2`` (or toward the rest shape's bends, ``rest_bending``). In compression the
membrane is ``compression`` times as stiff (a coarse triangle stands for cloth that buckles).
The body is the same capsules; a vertex at distance ``d`` from a capsule of
radius ``r`` with contact margin ``R`` (``collision_margin``) has the penalty ``contact_ke (r + R
- d)^2 / 2`` where that is positive (linear past ``release``, so cloth a fast limb carried
deep into it is not held there); a proxy's layers (``thickness`` ``L`` beneath the vertex)
add a soft ``layer_ke (r + R + L - d)^2 / 2`` (:mod:`core.sim.thickness`); and lagged Coulomb
friction (IPC's smoothed ``mu lambda f0(|u_T|)``, its normal force ``lambda`` and direction taken at the
step's start, the slip ``u_T`` against the capsule's own motion). Pinned vertices follow their
bones (kinematic, out of the solve). A single surface only: no cloth-cloth contact, no seams.

Everything is numpy float64 on the CPU; a step's cost is a few sparse factorisations. On the
quick project's 989-vertex proxy kept off the body by its layers, at 2 steps a frame to 0.3 mm
root mean square (the quick preset's ground truth) with bending's whole Hessian in the matrix
(``full_bending``), 55 to 352 ms a frame, median 154, over quick run q69's 46 clips; its runs
are 1.2x to 2.5x as far from runs twice as fine as from themselves on a 10 um nudge, the
cloth's own sensitivity (docs/decisions.md, "What counts as converged"; ``dng bench sim --set
solver=implicit --floor``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import qdldl
import scipy.sparse as sp

from core.body.colliders import closest_on_segments, is_arm, pose_capsules, segment_distances
from core.errors import InputError
from core.sim.config import IMPLICIT_NORMS

GRAVITY = np.array([0.0, -9.81, 0.0])
#: Slip speed (m/s) under which friction is static (IPC's smoothing of Coulomb's law).
FRICTION_EPS_V = 1.0e-3
#: Line search: shortest step tried, and the sufficient-decrease fraction (Armijo).
MIN_ALPHA = 1.0 / 64.0
ARMIJO = 1.0e-4
#: Fraction of the rest length below which a membrane softened in compression is stiff again.
COMPRESSION_KNEE = 0.5


@dataclass(frozen=True)
class ClothRest:
    """A garment's rest data for :class:`ImplicitCloth` (V vertices, T triangles).

    Attributes
    ----------
    faces : (T, 3) int64
    du, dv : (T, 3) float64, the derivatives of the deformation gradient's columns ``Fu``,
        ``Fv`` with respect to each corner (``Fu = sum_i du_i x_i``)
    area : (T,) float64 rest areas
    mass : (V,) float64 lumped masses (kg)
    bend : (V, V) sparse float64 Bergou's ``Q`` (times the bending stiffness)
    hinges : :class:`Hinges`, the interior edges ``Q`` sums over, with their rest bends
    """

    faces: np.ndarray
    du: np.ndarray
    dv: np.ndarray
    area: np.ndarray
    mass: np.ndarray
    bend: sp.csr_matrix
    hinges: Hinges


@dataclass(frozen=True)
class Hinges:
    """The interior edges of a mesh as Bergou's bending sees them (H hinges).

    Attributes
    ----------
    stencil : (H, 4) int64 the edge's ends, then the two opposite corners
    k : (H, 4) float64 the cotangent weights ``K``: ``K x`` (3,) is the hinge's bend, a vector
        along the sum of its two faces' normals, zero where the hinge is flat
    weight : (H,) float64 ``3 / (A0 + A1)`` times the bending stiffness (``Q = sum weight K K^T``)
    rest : (H,) float64 the rest bend's length, signed along the rest normals' sum
    """

    stencil: np.ndarray
    k: np.ndarray
    weight: np.ndarray
    rest: np.ndarray

    def rest_force(self, x: np.ndarray) -> np.ndarray:
        """(V, 3) ``sum weight K (rest m)``, ``m`` the hinges' normals at ``x``: the force with
        which bending toward the rest shape's bends, turned with the cloth, pulls each vertex
        (:class:`ImplicitCloth`'s ``rest_bending``)."""
        b = self.rest[:, None] * _hinge_normals(x, self.stencil)  # (H, 3) rest bends, turned
        pull = (self.weight[:, None, None] * self.k[:, :, None] * b[:, None, :]).reshape(-1, 3)
        at = self.stencil.ravel()
        return np.stack([np.bincount(at, pull[:, c], len(x)) for c in range(3)], axis=1)


def _hinge_normals(x: np.ndarray, stencil: np.ndarray) -> np.ndarray:
    """(H, 3) the unit sum of each hinge's two face normals, hinges (H, 4) :class:`Hinges`
    stencils, at positions ``x`` (V, 3)."""
    p0, p1, p2, p3 = (x[stencil[:, i]] for i in range(4))
    n0 = np.cross(p1 - p0, p2 - p0)
    n1 = np.cross(p3 - p0, p1 - p0)
    n0 /= np.maximum(np.linalg.norm(n0, axis=1), 1e-300)[:, None]
    n1 /= np.maximum(np.linalg.norm(n1, axis=1), 1e-300)[:, None]
    m = n0 + n1
    return m / np.maximum(np.linalg.norm(m, axis=1), 1e-12)[:, None]


def cloth_rest(
    vertices: np.ndarray, faces: np.ndarray, density: float, bend_ke: float
) -> ClothRest:
    """Rest data of a triangle mesh, each triangle laid flat in its own plane.

    Parameters
    ----------
    vertices : (V, 3) float, faces : (T, 3) int
    density : kg/m^2, bend_ke : N m (the fabric's)
    """
    x = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    if x.ndim != 2 or x.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or not len(f):
        raise InputError(f"cloth needs (V, 3) vertices and (T, 3) faces, got {x.shape}, {f.shape}")
    e1, e2 = x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]]
    l1 = np.linalg.norm(e1, axis=1)
    n = np.cross(e1, e2)
    twice = np.linalg.norm(n, axis=1)
    if (l1 <= 0).any() or (twice <= 1e-14).any():
        raise InputError("cloth has a degenerate (zero-area) triangle")
    u = e1 / l1[:, None]
    w = np.cross(n / twice[:, None], u)
    dm = np.stack(
        [np.stack([l1, (e2 * u).sum(1)], 1), np.stack([np.zeros_like(l1), (e2 * w).sum(1)], 1)], 1
    )
    inv = np.linalg.inv(dm)  # (T, 2, 2): columns of [x1 - x0, x2 - x0] @ inv are Fu, Fv
    du = np.stack([-inv[:, 0, 0] - inv[:, 1, 0], inv[:, 0, 0], inv[:, 1, 0]], 1)
    dv = np.stack([-inv[:, 0, 1] - inv[:, 1, 1], inv[:, 0, 1], inv[:, 1, 1]], 1)
    area = 0.5 * twice
    mass = np.bincount(f.ravel(), np.repeat(density * area / 3.0, 3), minlength=len(x))
    h = _hinges(x, f)
    hinges = Hinges(h.stencil, h.k, bend_ke * h.weight, h.rest)
    return ClothRest(f, du, dv, area, mass, bend_ke * _hinge_matrix(h, len(x)), hinges)


def bending_matrix(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Bergou et al.'s isometric bending form ``Q`` (V, V): ``E = x^T Q x / 2`` per coordinate.

    Per interior edge (x0, x1) between triangles with opposite vertices x2 and x3,
    ``Q += 3 / (A0 + A1) K K^T`` with ``K = (c03 + c04, c01 + c02, -c01 - c03, -c02 - c04)``
    on (x0, x1, x2, x3), ``c0j`` the cotangents of the angles the edge makes with the others
    (zero on a flat rest stencil: ``K`` annihilates every affine field there).
    """
    x = np.asarray(vertices, np.float64)
    return _hinge_matrix(_hinges(x, np.asarray(faces, np.int64)), len(x))


def _hinge_matrix(h: Hinges, v: int) -> sp.csr_matrix:
    q = h.weight[:, None, None] * h.k[:, :, None] * h.k[:, None, :]
    rows = np.repeat(h.stencil[:, :, None], 4, 2).ravel()
    cols = np.repeat(h.stencil[:, None, :], 4, 1).ravel()
    return sp.csr_matrix((q.ravel(), (rows, cols)), shape=(v, v))


def _hinges(vertices: np.ndarray, faces: np.ndarray) -> Hinges:
    """The interior edges of (V, 3) ``vertices`` and (T, 3) ``faces`` (:class:`Hinges`, at a
    bending stiffness of 1)."""
    x = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    half = np.concatenate([f[:, [0, 1, 2]], f[:, [1, 2, 0]], f[:, [2, 0, 1]]])  # (a, b, opposite)
    key = np.minimum(half[:, 0], half[:, 1]) * len(x) + np.maximum(half[:, 0], half[:, 1])
    order = np.argsort(key, kind="stable")
    k = key[order]
    first = np.flatnonzero((k[1:] == k[:-1]) & np.r_[True, k[1:-1] != k[:-2]])
    h0, h1 = half[order[first]], half[order[first + 1]]
    x0, x1, x2, x3 = h0[:, 0], h0[:, 1], h0[:, 2], h1[:, 2]
    p0, p1, p2, p3 = x[x0], x[x1], x[x2], x[x3]

    def cot(a, b):
        return (a * b).sum(1) / np.maximum(np.linalg.norm(np.cross(a, b), axis=1), 1e-14)

    e0 = p1 - p0
    c01, c02 = cot(e0, p2 - p0), cot(e0, p3 - p0)
    c03, c04 = cot(-e0, p2 - p1), cot(-e0, p3 - p1)
    kk = np.stack([c03 + c04, c01 + c02, -c01 - c03, -c02 - c04], 1)
    a0 = 0.5 * np.linalg.norm(np.cross(e0, p2 - p0), axis=1)
    a1 = 0.5 * np.linalg.norm(np.cross(e0, p3 - p0), axis=1)
    idx = np.stack([x0, x1, x2, x3], 1)
    bent = (kk[:, :, None] * x[idx]).sum(1)  # (H, 3) each hinge's rest bend K x
    return Hinges(idx, kk, 3.0 / (a0 + a1), (bent * _hinge_normals(x, idx)).sum(1))


def segment_gaps(y: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Every point's distance to every capsule axis: ``y`` (V, 3), ``ends`` (K, 2, 3) ->
    (V, K) float (:func:`core.body.colliders.segment_distances`)."""
    return segment_distances(y[:, None], ends[None, :, 0], ends[None, :, 1])


#: Pairs (vertex, capsule) whose gap exceeds this (metres) at a step's start and end positions
#: are left out of its contact terms (checked again at the step's solution).
CONTACT_PAD = 0.03


def _f0(u: np.ndarray, eps: float) -> np.ndarray:
    """IPC's smoothed slip magnitude (C1, equal to u from ``eps`` on)."""
    small = -(u**3) / (3 * eps**2) + u * u / eps + eps / 3
    return np.where(u < eps, small, u)


def _f1_over_u(u: np.ndarray, eps: float) -> np.ndarray:
    """f0'(u) / u, positive (the friction's Hessian weight along the slip)."""
    return np.where(u < eps, 2.0 / eps - u / eps**2, 1.0 / np.maximum(u, 1e-30))


class ImplicitCloth:
    """One garment's implicit steps, backward Euler or BDF2 (see the module docstring).

    Parameters
    ----------
    rest : ClothRest
    stretch_ke : N/m, ``ku = kv``; shear ``ks = stretch_ke / 2`` (as Style3D is set up here)
    contact_ke : N/m body-contact stiffness
    radius : (V,) float metres each vertex keeps from a capsule's surface (its margin), met at
        ``contact_ke``
    friction : (K,) float, each capsule's Coulomb coefficient
    capsule_radii : (K,) float
    pinned : (P,) int kinematic vertices
    tol : metres, the Newton update under which a step counts converged
    iterations : the most Newton iterations a step runs
    norm : ``"max"`` (the update's largest vertex) or ``"rms"`` (its root mean square over the
        vertices) against ``tol``
    layers : (V,) float metres of soft layers beyond each vertex's margin, or None (none)
    layer_ke : N/m with which those layers push back once the body presses into them
    full_bending : put bending's whole Hessian ``kb Q`` in the matrix, not its diagonal alone:
        more fill-in, but Newton converges where bending holds the cloth's shape against
        gravity (a hanging flap: :mod:`core.sim.tiers`), which the diagonal alone leaves to
        slow, linear convergence
    compression : the membrane's stiffness in compression over its stiffness in stretch
        (:meth:`_axial`)
    rest_bending : bend toward the rest shape's bends (:class:`Hinges`), turned with the cloth
        as it is at each step's start, instead of toward flat: ``kb |K y - b|^2 / 2`` per hinge
        with ``b`` the rest bend along the hinge's normal (the same matrix ``kb Q``; a force)
    release : metres past its margin's edge beyond which a vertex's push from the body stops
        growing (its energy goes on linearly)
    """

    def __init__(
        self, rest: ClothRest, stretch_ke: float, contact_ke: float, radius: np.ndarray,
        friction: np.ndarray, capsule_radii: np.ndarray, pinned: np.ndarray, tol: float,
        iterations: int, norm: str = "max", layers: np.ndarray | None = None,
        layer_ke: float = 0.0, full_bending: bool = False, compression: float = 1.0,
        rest_bending: bool = False, release: float = np.inf,
    ):  # fmt: skip
        self.rest = rest
        self.release = float(release)
        self.rest_bending = bool(rest_bending)
        self._bend_force = None  # (V, 3) the rest bends' pull this step (rest_bending)
        if not 0.0 < compression <= 1.0:
            raise InputError(f"compression must be in (0, 1], got {compression!r}")
        self.compression = float(compression)
        self.ku = self.kv = float(stretch_ke)
        self.ks = 0.5 * float(stretch_ke)
        self.contact_ke = float(contact_ke)
        # (V, K): the margin's reach (met at contact_ke) and, beyond it by the layers, the
        # reach of the layers (met at layer_ke); without layers the two are one
        self.solid = (
            np.asarray(radius, np.float64)[:, None] + np.asarray(capsule_radii, np.float64)[None]
        )
        self.reach = self.solid
        self.layer_ke = 0.0
        if layers is not None:
            self.reach = self.solid + np.asarray(layers, np.float64)[:, None]
            self.layer_ke = float(layer_ke)
        self.mu = np.asarray(friction, np.float64)
        self.tol, self.iterations = float(tol), int(iterations)
        if norm not in IMPLICIT_NORMS:
            raise InputError(f"implicit_norm must be one of {IMPLICIT_NORMS}, got {norm!r}")
        self.norm = norm
        v = len(rest.mass)
        free = np.ones(v, bool)
        free[np.asarray(pinned, np.int64)] = False
        self.free = free
        self.newton_iterations: list[int] = []
        self.full_bending = bool(full_bending)
        self.bend_diag = np.asarray(rest.bend.diagonal())
        self._factor = None  # qdldl's LDL^T: the ordering and symbolic pass once, then numbers
        t = len(rest.faces)
        self._g = np.stack([rest.du, rest.dv], 1)  # (T, 2, 3): (Fu, Fv) = g @ corners
        # (T, 9, 4): area g_ai g_bj, rows (i, j), columns (a, b), so a triangle's Hessian blocks
        # are this times its 2 x 2 blocks of 3 x 3 ((a, b) by (x, y)) in one batched product
        w = rest.area[:, None, None, None, None] * self._g[:, :, None, :, None]
        self._w = (w * self._g[:, None, :, None, :]).reshape(t, 4, 9).transpose(0, 2, 1).copy()
        self._pattern(v)

    # -- the matrix's sparsity, fixed: every value lands by one bincount -----------------------
    # Bending's Hessian (``kb Q``, constant) enters the matrix in full (``full_bending``) or by
    # its diagonal alone, its gradient in full either way. Its off-diagonal terms couple two
    # rings of neighbours, which multiplies a factorisation's fill-in; without them a stiff
    # bending converges linearly, and a step can meet the tolerance far from its solution.
    def _pattern(self, v: int) -> None:
        f = self.rest.faces
        vi = np.repeat(f[:, :, None], 3, 2)  # (T, 3, 3) row vertex
        vj = np.repeat(f[:, None, :], 3, 1)
        bend = self.rest.bend.tocoo()
        qi, qj = (bend.row, bend.col) if self.full_bending else (np.zeros(0, int),) * 2
        pairs_r = np.concatenate([vi.ravel(), np.arange(v), qi])
        pairs_c = np.concatenate([vj.ravel(), np.arange(v), qj])
        block = sp.csr_matrix((np.ones(len(pairs_r)), (pairs_r, pairs_c)), shape=(v, v))
        block.sum_duplicates()
        block.sort_indices()
        keep = self.free
        fidx = np.cumsum(keep) - 1  # free index of each vertex
        block = block[keep][:, keep].tocsr()
        block.sort_indices()
        nb = block.nnz
        # scalar CSR over 3 x free unknowns, built from the block pattern
        brow = np.repeat(np.arange(block.shape[0]), np.diff(block.indptr))
        bcol = block.indices
        rows = (3 * brow[:, None, None] + np.arange(3)[None, :, None]).repeat(3, 2)
        cols = (3 * bcol[:, None, None] + np.arange(3)[None, None, :]).repeat(3, 1)
        m = sp.csr_matrix(
            (np.arange(1, 9 * nb + 1, dtype=np.float64), (rows.ravel(), cols.ravel())),
            shape=(3 * block.shape[0],) * 2,
        )
        m.sort_indices()
        slot_of_block_entry = np.empty(9 * nb, np.int64)
        slot_of_block_entry[m.data.astype(np.int64) - 1] = np.arange(m.nnz)
        self._nnz, n = m.nnz, 3 * block.shape[0]
        self._n = n
        # the matrix is symmetric: its upper triangle (row <= column), column by column, is what
        # the LDL^T factorisation reads (the pattern is symmetric, so CSR's arrays read as CSC)
        col = np.repeat(np.arange(n), np.diff(m.indptr))
        upper = m.indices <= col
        self._upper = np.nonzero(upper)[0]
        self._up_indices = m.indices[upper]
        self._up_indptr = np.concatenate([[0], np.cumsum(np.bincount(col[upper], minlength=n))])

        keys = np.repeat(np.arange(block.shape[0]), np.diff(block.indptr)) * len(keep)
        keys = keys + block.indices  # sorted: CSR rows in order, columns sorted within them

        def block_slot(r: np.ndarray, c: np.ndarray) -> np.ndarray:
            """Index of block (r, c) (vertex ids) in ``block``; -1 where r or c is pinned."""
            ok = keep[r] & keep[c]
            out = np.full(r.shape, -1, np.int64)
            out[ok] = np.searchsorted(keys, fidx[r[ok]] * len(keep) + fidx[c[ok]])
            return out

        def scalar_slots(bslot: np.ndarray) -> np.ndarray:
            """(..., ) block slots -> (..., 3, 3) scalar slots (the dummy slot for -1)."""
            if not nb:  # nothing free
                return np.full(bslot.shape + (3, 3), self._nnz)
            base = np.where(bslot < 0, 0, bslot)[..., None, None] * 9 + np.arange(9).reshape(3, 3)
            out = slot_of_block_entry[base]
            return np.where(bslot[..., None, None] < 0, self._nnz, out)

        self._tri_slots = scalar_slots(block_slot(vi, vj))  # (T, 3, 3, 3, 3)
        diag = np.arange(v)
        self._diag_slots = scalar_slots(block_slot(diag, diag))  # (V, 3, 3)
        # bending's entries kb Q_ij on each block's diagonal (the same Q for x, y and z)
        three = np.arange(3)
        self._bend_slots = scalar_slots(block_slot(qi, qj))[:, three, three]  # (Q, 3)
        self._bend_values = np.repeat(bend.data if self.full_bending else np.zeros(0), 3)

    # -- the objective's terms ------------------------------------------------------------------
    def _axial(self, length: np.ndarray, k: float):
        """One direction's energy density (twice it), its slope and its curvature over ``k``, in
        its length ``|F|`` (T,): ``k (|F| - 1)^2 / 2`` in stretch; in compression
        ``compression`` times that (a coarse mesh's triangle stands for cloth that buckles,
        which costs little), and stiff again below :data:`COMPRESSION_KNEE` of the rest length
        (a triangle never vanishes). At ``compression = 1`` the plain quadratic, to the bit."""
        c = self.compression
        if c == 1.0:
            return k * (length - 1) ** 2, k * (length - 1), np.ones_like(length)
        soft = np.where(length < 1.0, c * k, k)
        below = np.minimum(length - COMPRESSION_KNEE, 0.0)
        hard = (1.0 - c) * k
        twice_energy = soft * (length - 1) ** 2 + hard * below**2
        slope = soft * (length - 1) + hard * below
        ratio = np.where(length < 1.0, c, 1.0) + np.where(below < 0, 1.0 - c, 0.0)
        return twice_energy, slope, ratio

    def _membrane(self, y: np.ndarray, hessian: bool, gradient: bool = True):
        r = self.rest
        f = np.matmul(self._g, y[r.faces])  # (T, 2, 3)
        fu, fv = f[:, 0], f[:, 1]
        lu, lv = np.linalg.norm(fu, axis=1), np.linalg.norm(fv, axis=1)
        uu, vv = fu / np.maximum(lu, 1e-12)[:, None], fv / np.maximum(lv, 1e-12)[:, None]
        c = (fu * fv).sum(1)
        a = r.area
        eu, du, ru = self._axial(lu, self.ku)
        ev, dv, rv = self._axial(lv, self.kv)
        energy = 0.5 * (a * (eu + ev + self.ks * c * c)).sum()
        if not gradient:
            return energy, None, None
        gu = a[:, None] * (du[:, None] * uu + self.ks * c[:, None] * fv)  # dE/dFu
        gv = a[:, None] * (dv[:, None] * vv + self.ks * c[:, None] * fu)
        grad = np.matmul(self._g.transpose(0, 2, 1), np.stack([gu, gv], 1))  # (T, 3, 3)
        if not hessian:
            return energy, grad, None
        eye = np.eye(3)
        su = np.clip(1.0 - 1.0 / np.maximum(lu, 1e-12), 0.0, None)  # compression's part dropped
        sv = np.clip(1.0 - 1.0 / np.maximum(lv, 1e-12), 0.0, None)
        huu = self.ku * (
            ru[:, None, None] * uu[:, :, None] * uu[:, None]
            + su[:, None, None] * (eye - uu[:, :, None] * uu[:, None])
        )
        hvv = self.kv * (
            rv[:, None, None] * vv[:, :, None] * vv[:, None]
            + sv[:, None, None] * (eye - vv[:, :, None] * vv[:, None])
        )
        # shear, Gauss-Newton: ks w w^T with w = (Fv, Fu)
        huu = huu + self.ks * fv[:, :, None] * fv[:, None]
        hvv = hvv + self.ks * fu[:, :, None] * fu[:, None]
        huv = self.ks * fv[:, :, None] * fu[:, None]
        blocks = np.stack([huu, huv, huv.transpose(0, 2, 1), hvv], 1).reshape(-1, 4, 9)
        h = np.matmul(self._w, blocks).reshape(-1, 3, 3, 3, 3)  # (T, corner i, corner j, 3, 3)
        return energy, grad, h

    def _contact(self, y: np.ndarray, ends: np.ndarray, pairs, hessian: bool, gradient=True):
        """Penalty on the candidate ``pairs`` (vertex (P,), capsule (P,), reach (P,)): the
        margin's ``contact_ke (solid - d)^2 / 2`` plus the layers' ``layer_ke (reach - d)^2 /
        2`` where each is positive."""
        vi, ki, reach = pairs
        solid = self.solid[vi, ki]
        if not gradient:
            d = segment_distances(y[vi], ends[ki, 0], ends[ki, 1])
            pen, soft = np.clip(solid - d, 0.0, None), np.clip(reach - d, 0.0, None)
            held = np.minimum(pen, self.release)
            energy = 0.5 * (
                self.contact_ke * (held * (2 * pen - held)).sum()
                + self.layer_ke * (soft * soft).sum()
            )
            return energy, None, None
        d, n, _ = closest_on_segments(y[vi], ends[ki, 0], ends[ki, 1])
        pen, soft = np.clip(solid - d, 0.0, None), np.clip(reach - d, 0.0, None)  # (P,)
        held = np.minimum(pen, self.release)  # past release, the push stops growing
        energy = 0.5 * (
            self.contact_ke * (held * (2 * pen - held)).sum() + self.layer_ke * (soft * soft).sum()
        )
        grad = np.zeros_like(y)
        np.add.at(grad, vi, -(self.contact_ke * held + self.layer_ke * soft)[:, None] * n)
        h = None
        if hessian:
            h = np.zeros((len(y), 3, 3))
            k = self.contact_ke * ((pen > 0) & (pen < self.release)) + self.layer_ke * (soft > 0)
            touch = k > 0
            np.add.at(h, vi[touch], k[touch, None, None] * n[touch, :, None] * n[touch, None, :])
        return energy, grad, h

    def _pairs(self, points: list[np.ndarray], ends: list[np.ndarray], pad: float, start=None):
        """(vertex, capsule, reach) of every pair within ``pad`` of touching at any of the
        given positions (V, 3) against any of the given segments (K, 2, 3), in (vertex,
        capsule) order.

        ``start``: (x (V, 3), ends0 (K, 2, 3), their gaps (V, K) from :func:`segment_gaps`), or
        None. A pair's gap moves by at most its vertex's move from ``x`` plus the largest move
        of its capsule's ends from ``ends0`` (every point of a segment moves by at most that),
        so only the pairs that this bound cannot rule out are measured: the same pairs, to
        the bit, as measuring them all, for a fraction of the cost (most of the body is far
        from most of the garment)."""
        limit = self.reach + pad
        if start is None:
            vi, ki = np.nonzero(np.ones(limit.shape, bool))
        else:
            x0, e0, gap0 = start
            move = np.max([np.linalg.norm(p - x0, axis=1) for p in points], 0)  # (V,)
            shift = np.max([np.linalg.norm(e - e0, axis=2).max(1) for e in ends], 0)  # (K,)
            vi, ki = np.nonzero(gap0 < limit + move[:, None] + shift[None] + 1e-9)
        hit = np.zeros(len(vi), bool)
        for p in points:
            for e in ends:
                hit |= segment_distances(p[vi], e[ki, 0], e[ki, 1]) < limit[vi, ki]
        vi, ki = vi[hit], ki[hit]
        return vi, ki, self.reach[vi, ki]

    def _friction(self, y: np.ndarray, lag, hessian: bool, gradient: bool = True):
        """Lagged friction: ``lag`` = (vertex (P,), weight ``mu lambda`` (P,), tangent
        projector (P, 3, 3), the start positions (V, 3), the body's motion at the contact over
        the step (P, 3), eps (m)), or None."""
        if lag is None:
            return 0.0, 0.0, None
        vi, w, proj, x0, body, eps = lag
        slip = np.einsum("pab,pb->pa", proj, y[vi] - x0[vi] - body)
        u = np.sqrt((slip * slip).sum(-1))
        energy = (w * _f0(u, eps)).sum()
        if not gradient:
            return energy, None, None
        k = w * _f1_over_u(u, eps)
        grad = np.zeros_like(y)
        np.add.at(grad, vi, k[:, None] * slip)
        h = None
        if hessian:
            h = np.zeros((len(y), 3, 3))
            np.add.at(h, vi, k[:, None, None] * proj)
        return energy, grad, h

    def _planes(self, y: np.ndarray, planes, hessian: bool, gradient: bool = True):
        """Penalty ``contact_ke (margin - (y - p) . n)^2 / 2`` where positive, on ``planes`` =
        (vertex (P,), point p (P, 3), unit normal n (P, 3), margin (metres)), or None: one-sided
        contact with a surface given per step (the cloth beneath a hanging piece)."""
        if planes is None:
            return 0.0, 0.0, None
        vi, p, n, margin = planes
        pen = np.clip(margin - ((y[vi] - p) * n).sum(1), 0.0, None)
        energy = 0.5 * self.contact_ke * (pen * pen).sum()
        if not gradient:
            return energy, None, None
        grad = np.zeros_like(y)
        np.add.at(grad, vi, -self.contact_ke * pen[:, None] * n)
        h = None
        if hessian:
            h = np.zeros((len(y), 3, 3))
            k = self.contact_ke * (pen > 0)
            np.add.at(h, vi, k[:, None, None] * n[:, :, None] * n[:, None, :])
        return energy, grad, h

    def _objective(
        self, y, target, inv_dt2, ends, pairs, lag, hessian: bool, gradient=True, planes=None
    ):
        """``E(y)``, its gradient (V, 3) (None unless ``gradient`` or ``hessian``: a line
        search needs only ``E``) and, if ``hessian``, the upper triangle (row <= column) of its
        positive semi-definite approximation over the free vertices' unknowns (CSC, 3 x free
        rows and columns), else None."""
        gradient = gradient or hessian
        m = self.rest.mass
        dy = y - target
        e_in = 0.5 * inv_dt2 * (m[:, None] * dy * dy).sum()
        e_m, g_tri, h_tri = self._membrane(y, hessian, gradient)
        by = self.rest.bend @ y
        e_b = 0.5 * (y * by).sum()
        if self._bend_force is not None:  # toward the rest bends, turned as at the step's start
            by = by - self._bend_force
            e_b = e_b - (y * self._bend_force).sum()
        e_c, g_c, h_c = self._contact(y, ends, pairs, hessian, gradient)
        e_f, g_f, h_f = self._friction(y, lag, hessian, gradient)
        e_p, g_p, h_p = self._planes(y, planes, hessian, gradient)
        energy = e_in + e_m + e_b + e_c + e_f + e_p
        if not gradient:
            return energy, None, None
        grad = inv_dt2 * m[:, None] * dy + by + g_c + g_f + g_p
        np.add.at(grad, self.rest.faces.ravel(), g_tri.reshape(-1, 3))
        if not hessian:
            return energy, grad, None
        bend_diag = 0.0 if self.full_bending else self.bend_diag
        diag = (inv_dt2 * m + bend_diag)[:, None, None] * np.eye(3) + h_c
        if h_f is not None:
            diag = diag + h_f
        if h_p is not None:
            diag = diag + h_p
        data = np.bincount(self._tri_slots.ravel(), h_tri.ravel(), minlength=self._nnz + 1)
        data += np.bincount(self._diag_slots.ravel(), diag.ravel(), minlength=self._nnz + 1)
        if self.full_bending:
            data += np.bincount(
                self._bend_slots.ravel(), self._bend_values, minlength=self._nnz + 1
            )
        matrix = sp.csc_matrix(
            (data[self._upper], self._up_indices, self._up_indptr), shape=(self._n, self._n)
        )
        return energy, grad, matrix

    def _solve(self, upper: sp.csc_matrix, g: np.ndarray) -> np.ndarray:
        """The Newton step ``-H^{-1} g`` from ``H``'s upper triangle (``n x n`` CSC, the fixed
        pattern): qdldl's LDL^T without pivoting (``H`` is positive definite: the inertia plus
        terms made positive semi-definite), its AMD ordering and symbolic factorisation made
        on the first call and reused. Non-finite where ``H`` is singular or not finite."""
        try:
            if self._factor is None:
                self._factor = qdldl.Solver(upper, upper=True)
            else:
                self._factor.update(upper, upper=True)
            return -self._factor.solve(g)
        except (ValueError, RuntimeError):  # a zero pivot, reported rather than divided by
            self._factor = None
            return np.full_like(g, np.nan)

    def _friction_lag(self, x, ends0, ends1, gap0: np.ndarray, dt: float):
        """The friction's lagged terms (:meth:`_friction`) from the contacts at the step's
        start (``gap0`` (V, K): :func:`segment_gaps` of ``x`` against ``ends0``), or None
        without any."""
        lam = self.contact_ke * np.clip(self.solid - gap0, 0.0, None)
        if self.layer_ke:
            lam = lam + self.layer_ke * np.clip(self.reach - gap0, 0.0, None)
        lam = lam * self.mu[None]
        vi, ki = np.nonzero(lam > 0)
        if not len(vi):
            return None
        _, n, s = closest_on_segments(x[vi], ends0[ki, 0], ends0[ki, 1])
        proj = np.eye(3) - n[:, :, None] * n[:, None, :]
        move = ends1[ki] - ends0[ki]  # (P, 2, 3): the contact point moves with the segment
        body = (1 - s)[:, None] * move[:, 0] + s[:, None] * move[:, 1]
        return vi, lam[vi, ki], proj, x, body, FRICTION_EPS_V * dt

    def step(
        self, x: np.ndarray, v: np.ndarray, pinned_to: np.ndarray, ends0: np.ndarray,
        ends1: np.ndarray, dt: float, before=None, planes=None,
    ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """One implicit step: backward Euler, or BDF2 given the step before.

        Parameters
        ----------
        x, v : (V, 3) float positions and velocities at the step's start
        pinned_to : (P, 3) float the pinned vertices' positions at its end
        ends0, ends1 : (K, 2, 3) float the capsules' segments at its start and end
        dt : seconds
        before : (x, v) (V, 3) float at the start of the step before, as long as this one, for
            BDF2 (second order: ``y = x~ + h^2 a(y)`` with ``h = 2 dt / 3`` and
            ``x~ = 4/3 x - 1/3 x' + h (4/3 v - 1/3 v')``); None: backward Euler (first order,
            whose numerical damping of a swing grows with the step)
        planes : (vertex (P,), point (P, 3), unit normal (P, 3), margin) one-sided contact
            planes for this step (:meth:`_planes`), or None

        Returns
        -------
        (V, 3) float64 positions and velocities at the step's end
        """
        x = np.asarray(x, np.float64)
        v = np.asarray(v, np.float64)
        if before is None:
            h, base = dt, x + dt * v
        else:
            xb, vb = (np.asarray(a, np.float64) for a in before)
            h = 2.0 * dt / 3.0
            base = (4 * x - xb) / 3 + h * (4 * v - vb) / 3
        target = base + h * h * GRAVITY
        y = x + dt * v
        y[~self.free] = pinned_to
        inv_dt2 = 1.0 / (h * h)
        if self.rest_bending:
            self._bend_force = self.rest.hinges.rest_force(x)
        gap0 = segment_gaps(x, ends0)
        start = (x, ends0, gap0)  # the step's start: every gap the contact pairs need bounds
        lag = self._friction_lag(x, ends0, ends1, gap0, dt)
        pairs = self._pairs([x, y], [ends0, ends1], CONTACT_PAD, start)
        free = self.free
        used, k = self.iterations, 0
        while k < self.iterations:
            k += 1
            energy, grad, matrix = self._objective(
                y, target, inv_dt2, ends1, pairs, lag, True, True, planes
            )
            g = grad[free].ravel()
            if not len(g):  # every vertex kinematic
                break
            step = self._solve(matrix, g)
            if not np.isfinite(step).all():  # a singular matrix: non-finite input; the caller's
                y = np.full_like(y, np.nan)  # checks see a blown-up step and retry it finer
                break
            p = np.zeros_like(y)
            p[free] = step.reshape(-1, 3)
            slope = float(g @ step)
            alpha = 1.0
            while alpha >= MIN_ALPHA:
                trial = y + alpha * p
                e_new = self._objective(
                    trial, target, inv_dt2, ends1, pairs, lag, False, False, planes
                )
                if e_new[0] <= energy + ARMIJO * alpha * slope:
                    break
                alpha *= 0.5
            y = y + alpha * p
            size = np.abs(p).max() if self.norm == "max" else np.sqrt((p * p).sum(1).mean())
            if alpha * size < self.tol:
                missed = self._pairs([y], [ends1], 0.0, start)
                known = set(zip(pairs[0].tolist(), pairs[1].tolist()))
                new = [i for i, vk in enumerate(zip(*missed[:2])) if vk not in known]
                if not new:  # no contact left out: converged
                    used = k
                    break
                pairs = tuple(np.concatenate([a, b[new]]) for a, b in zip(pairs, missed))
        self.newton_iterations.append(used)
        if before is None:
            return y, (y - x) / dt
        return y, (3 * y - 4 * x + before[0]) / (2 * dt)


class ImplicitScene:
    """The implicit solver behind :func:`core.sim.simulate.simulate`'s scene interface
    (``step``, ``positions``, ``velocities``, ``snapshot``, ``restore``), for a single surface.

    ``InputError`` for a garment that needs cloth-cloth contact or seams (several pieces)."""

    device = "cpu"

    def __init__(self, garment, config, capsules, pins, seams, m0: np.ndarray, thickness=None):
        if config.self_collision or len(seams.indices):
            raise InputError(
                "the implicit solver simulates a single surface (a proxy); this garment has "
                "several pieces (layers or sewn parts): simulate it with --solver style3d"
            )
        fab = config.material
        friction = config.layer_friction if thickness is not None else fab.friction
        self.capsules = capsules
        self.config = config
        self.pins = pins
        radius = np.full(garment.num_vertices, config.collision_margin)
        layered = thickness is not None
        stiffer = config.layer_bending if layered else 1.0
        squeeze = config.layer_compression if thickness is not None else config.compression
        rest = cloth_rest(garment.vertices, garment.faces, fab.density, fab.bend_ke * stiffer)
        mu = np.array([0.0 if is_arm(name) else friction for name in capsules.names])
        self.cloth = ImplicitCloth(
            rest, fab.stretch_ke, config.contact_ke, radius, mu, capsules.radii,
            pins.indices, config.implicit_tol, config.iterations, config.implicit_norm,
            thickness, config.layer_ke, compression=squeeze,
            rest_bending=config.rest_bending, full_bending=layered and config.layer_full_bending,
            release=config.layer_release if thickness is not None else np.inf,
        )  # fmt: skip
        self.x = garment.vertices.astype(np.float64)
        self.v = np.zeros_like(self.x)
        self.order = config.implicit_order
        self.before = None  # (x, v, dt) at the previous step's start, for BDF2

    def body_poses(self, transforms: np.ndarray) -> np.ndarray:
        """The capsules' segments for skinning transforms (..., J, 4, 4): (..., K, 2, 3)."""
        return pose_capsules(self.capsules, np.asarray(transforms))

    def step(self, ma: np.ndarray, mb: np.ndarray, dt: float, poses: tuple | None = None) -> None:
        """One step with the body moving from transforms ``ma`` to ``mb`` (J, 4, 4);
        ``poses``: their segments (:meth:`body_poses`) when already computed."""
        if poses is None:
            ends0, ends1 = self.body_poses(ma[None])[0], self.body_poses(mb[None])[0]
        else:
            ends0, ends1 = poses[0], poses[1]
        pinned_to = self.pins.targets(mb).astype(np.float64)
        b = self.before
        history = b[:2] if self.order == 2 and b is not None and b[2] == dt else None
        self.before = (self.x, self.v, dt)
        self.x, self.v = self.cloth.step(self.x, self.v, pinned_to, ends0, ends1, dt, history)
        if self.config.damping > 0:
            self.v *= np.exp(-self.config.damping * dt)

    def positions(self) -> np.ndarray:
        return self.x.astype(np.float32)

    def velocities(self) -> np.ndarray:
        return self.v.astype(np.float32)

    def snapshot(self) -> tuple:
        return self.x.copy(), self.v.copy(), self.before

    def restore(self, snap: tuple) -> None:
        self.x, self.v, self.before = snap[0].copy(), snap[1].copy(), snap[2]
