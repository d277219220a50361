"""The implicit Euler solver by Newton's method (``solver="implicit"``, scipy only: no warp)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp

from core.body.shape import BodyShape
from core.errors import InputError
from core.mesh import unique_edges
from core.sim import implicit
from core.sim.config import SimConfig
from core.sim.implicit import (
    CONTACT_PAD,
    ImplicitCloth,
    bending_matrix,
    cloth_rest,
    segment_gaps,
)
from core.sim.simulate import edge_strain, simulate
from tests.sim_helpers import frustum_skirt, spin_motion, two_layer_skirt

FAST = SimConfig(solver="implicit", substeps=2, iterations=8, transition_s=0.2, settle_s=0.2)


def _sheet(n: int = 8, size: float = 0.5):
    """A flat square n x n grid in the y = 1 plane: (n^2, 3) vertices, faces."""
    xs, zs = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n))
    v = np.stack([xs.ravel(), np.ones(n * n), zs.ravel()], 1)
    i = np.arange(n * n).reshape(n, n)
    a = np.stack([i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[:-1, 1:].ravel()], 1)
    b = np.stack([i[1:, 1:].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel()], 1)
    return v, np.concatenate([a, b]), i


def _numeric_gradient(energy, y: np.ndarray, step: float = 1e-7) -> np.ndarray:
    """Central differences of ``energy`` (a function of (V, 3) positions) at ``y``: (V, 3)."""
    num = np.zeros_like(y)
    for a in range(len(y)):
        for c in range(3):
            yp, ym = y.copy(), y.copy()
            yp[a, c] += step
            ym[a, c] -= step
            num[a, c] = (energy(yp) - energy(ym)) / (2 * step)
    return num


def test_bending_form_is_symmetric_and_leaves_a_flat_sheet_alone():
    v, f, _ = _sheet()
    q = bending_matrix(v, f)
    assert abs(q - q.T).max() < 1e-9
    # Zero on any affine field of a flat rest sheet; positive on a bent one.
    affine = v @ np.array([[0.3, -1.0, 2.0], [0.5, 0.2, 0.1], [1.0, 0.0, -0.4]])
    assert np.abs(q @ affine).max() < 1e-8
    bent = v.copy()
    bent[:, 1] += 2.0 * (v[:, 0] - 0.25) ** 2
    assert (bent * (q @ bent)).sum() > 1.0


def test_gradient_and_hessian_match_finite_differences():
    v, f, i = _sheet(4)
    rest = cloth_rest(v, f, 0.15, 0.0)  # the matrix keeps only bending's diagonal: none here
    ends = np.array([[[0.1, 1.12, 0.1], [0.4, 1.12, 0.1]]])
    cloth = ImplicitCloth(rest, 5e3, 1e4, np.full(len(v), 0.004), np.zeros(1), np.array([0.15]),
                          i[0], 1e-5, 8)  # fmt: skip
    cloth.ks = 0.0  # shear's indefinite part is dropped from the Hessian: compare without it
    rng = np.random.default_rng(0)
    y = 1.2 * v + 0.01 * rng.standard_normal(v.shape)  # stretched (no compression), one contact
    target = v.copy()
    far = ends + 10.0  # the contact's Hessian drops its negative (curvature) part: check apart
    near, apart = cloth._pairs([y], [ends], 1.0), cloth._pairs([y], [far], 0.0)
    e, g, _ = cloth._objective(y, target, 100.0, ends, near, None, True)
    upper = cloth._objective(y, target, 100.0, far, apart, None, True)[2]  # its upper triangle
    h = upper + sp.triu(upper, 1).T
    assert (segment_gaps(y, ends) < 0.154).any()
    step = 1e-6
    num_g = np.zeros_like(y)
    num_h = np.zeros((h.shape[0], h.shape[0]))
    free = np.flatnonzero(cloth.free)
    col = 0
    for a in range(len(y)):
        for c in range(3):
            yp, ym = y.copy(), y.copy()
            yp[a, c] += step
            ym[a, c] -= step
            ep = cloth._objective(yp, target, 100.0, ends, near, None, False)[0]
            em = cloth._objective(ym, target, 100.0, ends, near, None, False)[0]
            num_g[a, c] = (ep - em) / (2 * step)
            if a in free:
                gp = cloth._objective(yp, target, 100.0, far, apart, None, False)[1]
                gm = cloth._objective(ym, target, 100.0, far, apart, None, False)[1]
                num_h[:, col] = ((gp - gm) / (2 * step))[cloth.free].ravel()
                col += 1
    assert np.abs(num_g - g).max() < 1e-5 * np.abs(g).max()
    assert np.abs(num_h - h.toarray()).max() < 1e-4 * np.abs(num_h).max()


def test_the_soft_layers_contact_gradient_matches_finite_differences():
    """Beyond the margin (met at ``contact_ke``) a proxy's layers push back at ``layer_ke``:
    the contact's energy is ``contact_ke (solid - d)^2 / 2 + layer_ke (reach - d)^2 / 2``, and
    its gradient is that energy's, with vertices in the layers only and in both."""
    v, f, i = _sheet(6, 0.3)
    ends = np.array([[[0.0, 0.9, 0.15], [0.3, 0.9, 0.15]]])
    layers = np.linspace(0.0, 0.1, len(v))
    cloth = ImplicitCloth(cloth_rest(v, f, 0.15, 0.0), 5e3, 1e4, np.full(len(v), 0.004),
                          np.zeros(1), np.array([0.05]), i[0], 1e-5, 8, layers=layers,
                          layer_ke=30.0)  # fmt: skip
    rng = np.random.default_rng(1)
    y = v - np.array([0.0, 0.06, 0.0]) + 0.005 * rng.standard_normal(v.shape)
    pairs = cloth._pairs([y], [ends], 0.0)
    d = segment_gaps(y, ends)[:, 0]
    solid, reach = 0.054, 0.054 + layers
    assert ((d < solid).sum() > 2) and ((d > solid) & (d < reach)).sum() > 2  # both zones
    e, g, _ = cloth._contact(y, ends, pairs, False)
    expect = 0.5 * (1e4 * np.clip(solid - d, 0, None) ** 2).sum()
    expect += 0.5 * (30.0 * np.clip(reach - d, 0, None) ** 2).sum()
    assert e == pytest.approx(expect, rel=1e-9)
    num = _numeric_gradient(lambda z: cloth._contact(z, ends, pairs, False, False)[0], y)
    assert np.abs(num - g).max() < 1e-5 * np.abs(g).max()


@pytest.mark.parametrize(("layer_ke", "low", "high"), [(1e4, 0.028, 0.031), (10.0, 0.0, 0.026)])
def test_layers_hold_a_sheet_off_a_bar_rigidly_or_give_under_its_weight(layer_ke, low, high):
    """A pinned sheet hangs over a bar with 30 mm of layers beneath every vertex: at
    ``contact_ke`` they hold it 30 mm off (a rigid shell); at 10 N/m its weight presses it into
    them, but not through the margin."""
    v, f, i = _sheet(10, 0.6)
    ends = np.array([[[0.1, 0.9, 0.3], [0.5, 0.9, 0.3]]])
    cloth = ImplicitCloth(cloth_rest(v, f, 0.15, 2e-5), 5e3, 1e4, np.full(len(v), 0.004),
                          np.zeros(1), np.array([0.05]), i[0], 1e-5, 16,
                          layers=np.full(len(v), 0.03), layer_ke=layer_ke)  # fmt: skip
    x, vel = v.copy(), np.zeros_like(v)
    for _ in range(240):  # 1 s at 240 steps a second
        x, vel = cloth.step(x, vel, v[i[0]], ends, ends, 1 / 240)
    into = 0.054 + 0.03 - segment_gaps(x, ends).min()  # deepest into the layers
    assert np.isfinite(x).all()
    assert low <= 0.03 - into <= high, 0.03 - into  # what is left of the layers, metres
    assert segment_gaps(x, ends).min() > 0.054 - 0.001  # never through the margin


def test_contact_pairs_pruned_by_the_step_start_are_the_pairs_of_every_gap():
    """The contact candidates measured only where the step start's gaps cannot rule them
    out are the same pairs, in the same order, as measuring every vertex against every
    capsule at the step's start and end positions and segments."""
    v, f, i = _sheet(8)
    rng = np.random.default_rng(3)
    cloth = ImplicitCloth(cloth_rest(v, f, 0.15, 0.0), 5e3, 1e4, np.full(len(v), 0.004),
                          np.zeros(3), np.array([0.05, 0.08, 0.03]), i[0], 1e-5, 8)  # fmt: skip
    ends0 = np.array(
        [[[0.0, 1.05, 0.1], [0.5, 1.05, 0.1]], [[0.2, 0.9, 0.0], [0.2, 0.9, 0.5]],
         [[3.0, 3.0, 3.0], [3.1, 3.0, 3.0]]]
    )  # fmt: skip
    for _ in range(5):
        x = v + 0.02 * rng.standard_normal(v.shape)
        y = x + 0.01 * rng.standard_normal(v.shape)
        ends1 = ends0 + 0.02 * rng.standard_normal(ends0.shape)
        start = (x, ends0, segment_gaps(x, ends0))
        for points, ends, pad in (([x, y], [ends0, ends1], 0.03), ([y], [ends1], 0.0)):
            every = cloth._pairs(points, ends, pad)
            pruned = cloth._pairs(points, ends, pad, start)
            assert len(every[0]) > 0
            for a, b in zip(every, pruned):
                assert np.array_equal(a, b)


def test_a_contact_no_candidate_foresaw_is_added_when_the_step_converges():
    """A sheet falls 5 cm in one step onto a bar that was beyond every candidate's reach at
    the step's start (6 cm below it, 3.6 cm clear of touching): the converged step finds the
    missed pairs, adds them and solves again until no contact is left out, so the row above
    the bar ends on it, not in it."""
    v, f, _ = _sheet(11, 0.6)  # a row of vertices at z = 0.3, over the bar
    bar = np.array([[[0.1, 0.94, 0.3], [0.5, 0.94, 0.3]]])
    cloth = ImplicitCloth(cloth_rest(v, f, 0.15, 0.0), 5e3, 1e4, np.full(len(v), 0.004),
                          np.zeros(1), np.array([0.02]), np.zeros(0, np.int64), 3e-4, 80)  # fmt: skip
    assert not len(cloth._pairs([v], [bar], CONTACT_PAD, (v, bar, segment_gaps(v, bar)))[0])
    x, _ = cloth.step(v, np.zeros_like(v), np.zeros((0, 3)), bar, bar, 0.0714)
    over = (np.abs(v[:, 0] - 0.3) < 0.15) & (np.abs(v[:, 2] - 0.3) < 0.01)
    assert np.isfinite(x).all() and over.sum() == 5
    assert cloth.newton_iterations[0] < 80  # converged, the missed contacts in
    assert segment_gaps(x[over], bar).min() > 0.024 - 1e-4  # on the bar (its reach 24 mm)
    assert x[:, 1].min() < 1.0 - 0.05  # and fell 5 cm to it


def test_a_pinned_sheet_hangs_on_a_capsule_without_stretching_or_passing_through():
    v, f, i = _sheet(10, 0.6)
    rest = cloth_rest(v, f, 0.15, 2e-5)
    ends = np.array([[[0.1, 0.8, 0.3], [0.5, 0.8, 0.3]]])  # a bar 0.2 m under the sheet
    cloth = ImplicitCloth(rest, 5e3, 1e4, np.full(len(v), 0.004), np.array([0.3]),
                          np.array([0.05]), i[0], 1e-5, 16)  # fmt: skip
    x, vel = v.copy(), np.zeros_like(v)
    for _ in range(120):  # 0.5 s at 240 steps a second
        x, vel = cloth.step(x, vel, v[i[0]], ends, ends, 1 / 240)
    assert np.allclose(x[i[0]], v[i[0]])  # pinned
    e = unique_edges(f)
    strain = edge_strain(x[None], e, np.linalg.norm(v[e[:, 1]] - v[e[:, 0]], axis=1))
    assert strain.max() < 0.05
    assert x[:, 1].min() < 0.7  # draped down past the bar
    assert segment_gaps(x, ends).min() > 0.05 + 0.004 - 0.001  # not through it
    assert np.mean(cloth.newton_iterations) < 8  # most steps converge well before the cap


def test_the_rms_norm_stops_sooner_and_close_to_the_max_norm():
    """A sheet pinned along one edge swings down for 0.5 s at 60 steps a second: measured by
    its root mean square, a step's update meets the tolerance in fewer Newton iterations than
    by its largest vertex, and the sheet ends within a millimetre of that run."""
    v, f, i = _sheet(10, 0.6)
    rest = cloth_rest(v, f, 0.15, 2e-5)
    far = np.array([[[10.0, 10.0, 10.0], [11.0, 10.0, 10.0]]])
    runs = {}
    for norm in ("max", "rms"):
        cloth = ImplicitCloth(rest, 5e3, 1e4, np.full(len(v), 0.004), np.zeros(1),
                              np.array([0.05]), i[0], 1e-4, 40, norm)  # fmt: skip
        x, vel, before = v.copy(), np.zeros_like(v), None
        for _ in range(30):
            x_new, v_new = cloth.step(x, vel, v[i[0]], far, far, 1 / 60, before)
            before, x, vel = (x, vel), x_new, v_new
        runs[norm] = x, np.mean(cloth.newton_iterations)
    assert runs["rms"][1] < runs["max"][1]
    assert np.linalg.norm(runs["rms"][0] - runs["max"][0], axis=1).mean() < 1e-3
    with pytest.raises(InputError, match="implicit_norm"):
        ImplicitCloth(rest, 5e3, 1e4, np.full(len(v), 0.004), np.zeros(1), np.array([0.05]),
                      i[0], 1e-4, 40, "l2")  # fmt: skip
    with pytest.raises(InputError, match="implicit_norm"):
        replace(FAST, implicit_norm="l2")


def test_simulate_with_the_implicit_solver():
    skirt = frustum_skirt(24, 12)
    cache, report = simulate(skirt, spin_motion(4), BodyShape(), FAST)
    assert cache.params["solver"] == "core.sim.implicit.ImplicitCloth"
    assert cache.positions.shape == (4, skirt.num_vertices, 3) and report.finite
    assert report.strain_max < report.strain_limit
    assert report.penetration_mean_mm < 2.0
    assert cache.positions[0, :, 1].min() < skirt.vertices[:, 1].min()  # the hem sank
    # the pinned waistband follows the pelvis; the hem's rise along it is measured
    assert 0.0 <= report.waistband_rise_max_mm < 5.0 and np.isfinite(report.hem_rise_end_mm)


def test_the_pelvis_of_the_report_is_the_motions_hips_and_spine():
    """The report's waistband and hem rises are along the hips joint and Spine1 of the body as
    simulated: the same joints the motion's canonical positions give, frame by frame."""
    from core.body.shape import mannequin_skeleton
    from core.motion.mapping import MAPPED_JOINTS, canonical_positions
    from core.motion.procedural import make_motion
    from core.sim.simulate import _pelvis, prepare

    motion = make_motion("kick", 20, 30.0, 0, BodyShape())
    run = prepare(frustum_skirt(24, 12), motion, BodyShape(), FAST)
    pelvis = _pelvis(mannequin_skeleton(BodyShape()), run.drive)
    joints = canonical_positions(motion)
    spine, left, right = (MAPPED_JOINTS.index(n) for n in ("Spine1", "LeftFoot", "RightFoot"))
    np.testing.assert_allclose(pelvis.hips, joints[:, 0], atol=2e-3)
    np.testing.assert_allclose(pelvis.up, joints[:, spine] - joints[:, 0], atol=2e-3)
    np.testing.assert_allclose(pelvis.feet, joints[:, [left, right]], atol=2e-3)


def test_implicit_solver_refuses_a_layered_garment_and_a_bad_tolerance():
    with pytest.raises(InputError, match="single surface"):
        simulate(two_layer_skirt(), spin_motion(2), BodyShape(), FAST)
    with pytest.raises(InputError, match="implicit_tol"):
        replace(FAST, implicit_tol=0.0)


def test_bdf2_converges_with_the_step_where_backward_euler_damps():
    """A sheet pinned along one edge swings down from level for 0.5 s, at steps of 1/60, 1/120
    and 1/240 s: BDF2's answers close in faster as the step halves (second order)."""
    v, f, i = _sheet(6, 0.4)
    rest = cloth_rest(v, f, 0.15, 2e-5)
    far = np.array([[[10.0, 10.0, 10.0], [11.0, 10.0, 10.0]]])

    def swing(dt: float, order: int) -> np.ndarray:
        cloth = ImplicitCloth(rest, 5e3, 1e4, np.full(len(v), 0.004), np.zeros(1),
                              np.array([0.05]), i[0], 1e-7, 30)  # fmt: skip
        x, vel, before = v.copy(), np.zeros_like(v), None
        for _ in range(round(0.5 / dt)):
            x_new, v_new = cloth.step(x, vel, v[i[0]], far, far, dt, before if order == 2 else None)
            before, x, vel = (x, vel), x_new, v_new
        return x

    def gaps(order: int) -> tuple[float, float]:
        a, b, c = (swing(dt, order) for dt in (1 / 60, 1 / 120, 1 / 240))
        return np.linalg.norm(a - b, axis=1).mean(), np.linalg.norm(b - c, axis=1).mean()

    euler, bdf2 = gaps(1), gaps(2)
    assert bdf2[1] < 0.4 * euler[1]
    assert bdf2[0] / bdf2[1] > 2.2 > euler[0] / euler[1]


def test_a_step_from_nan_comes_back_non_finite_for_the_callers_checks():
    v, f, i = _sheet(4)
    cloth = ImplicitCloth(cloth_rest(v, f, 0.15, 2e-5), 5e3, 1e4, np.full(len(v), 0.004),
                          np.zeros(1), np.array([0.05]), i[0], 1e-5, 8)  # fmt: skip
    far = np.array([[[10.0, 10.0, 10.0], [11.0, 10.0, 10.0]]])
    x = v.copy()
    x[5] = np.nan
    y, vel = cloth.step(x, np.zeros_like(v), v[i[0]], far, far, 1 / 240)
    assert not np.isfinite(y).all() and y.shape == v.shape
    y, _ = cloth.step(v, np.zeros_like(v), v[i[0]], far, far, 1 / 240)  # a retry from a finite
    assert np.isfinite(y).all()  # state factorises afresh
    every = ImplicitCloth(cloth_rest(v, f, 0.15, 2e-5), 5e3, 1e4, np.full(len(v), 0.004),
                          np.zeros(1), np.array([0.05]), np.arange(len(v)), 1e-5, 8)  # fmt: skip
    y, _ = every.step(v, np.zeros_like(v), v + 0.01, far, far, 1 / 240)
    assert np.allclose(y, v + 0.01)  # all kinematic: placed where their bones put them


# ------------------------------------------------- the proxy's cloth: buckling, rest bends, release


def _curved_sheet(n: int = 7):
    """A sheet bent round a cylinder of radius 0.3 m (a third of a turn): vertices, faces."""
    v, f, i = _sheet(n, 0.5)
    angle = (v[:, 0] - 0.25) / 0.3
    curved = np.stack([0.3 * np.sin(angle), 1.0 + 0.3 * (1 - np.cos(angle)), v[:, 2]], 1)
    return curved, f, i


def test_the_membrane_soft_in_compression_matches_finite_differences_and_is_the_plain_one_at_1():
    v, f, i = _sheet(4)
    rng = np.random.default_rng(2)
    y = 0.8 * v + 0.01 * rng.standard_normal(v.shape)  # mostly shortened, a little sheared
    y[:, 1] = 1.0 + 0.3 * rng.standard_normal(len(v)) * 0.05
    plain = ImplicitCloth(cloth_rest(v, f, 0.15, 0.0), 5e3, 1e4, np.full(len(v), 0.004),
                          np.zeros(1), np.array([0.05]), i[0], 1e-5, 8)  # fmt: skip
    soft = ImplicitCloth(plain.rest, 5e3, 1e4, np.full(len(v), 0.004), np.zeros(1),
                         np.array([0.05]), i[0], 1e-5, 8, compression=0.01)  # fmt: skip
    same = ImplicitCloth(plain.rest, 5e3, 1e4, np.full(len(v), 0.004), np.zeros(1),
                         np.array([0.05]), i[0], 1e-5, 8, compression=1.0)  # fmt: skip
    for a, b in zip(plain._membrane(y, True), same._membrane(y, True)):
        assert np.array_equal(a, b)  # 1: the plain quadratic, to the bit
    e_plain, e_soft = plain._membrane(y, False)[0], soft._membrane(y, False)[0]
    assert e_soft < 0.2 * e_plain  # shortening costs little
    g = np.zeros_like(y)
    np.add.at(g, f.ravel(), soft._membrane(y, False)[1].reshape(-1, 3))
    num = _numeric_gradient(lambda z: soft._membrane(z, False, False)[0], y)
    assert np.abs(num - g).max() < 1e-5 * np.abs(g).max()
    # stretch is met as before; a triangle squashed below half its length is stiff again
    assert soft._axial(np.array([1.1]), 5e3)[1] == plain._axial(np.array([1.1]), 5e3)[1]
    slope = soft._axial(np.array([0.9, 0.4]), 5e3)[1]
    assert slope[0] == pytest.approx(0.01 * 5e3 * -0.1)
    assert slope[1] < 0.99 * 5e3 * -0.1


def test_rest_bending_holds_a_curved_sheet_where_flat_bending_straightens_it():
    # No gravity, no body: a curved sheet pinned along one straight edge, left to itself. Flat
    # bending unbends it; bending toward its rest bends leaves it where it is, and so does a
    # rigid turn of the whole sheet (the rest bends turn with it).
    v, f, i = _curved_sheet()
    pinned = i[:, 3]  # the line x = 0.25 across the sheet's middle, where it is straight
    rest = cloth_rest(v, f, 0.15, 2e-3)
    assert np.abs(rest.bend @ v).max() > 1e-3  # flat bending pulls at the rest shape
    assert np.abs(rest.bend @ v - rest.hinges.rest_force(v)).max() < 1e-12

    def run(x0, rest_bending):
        cloth = ImplicitCloth(rest, 5e3, 1e4, np.full(len(v), 0.004), np.zeros(1),
                              np.array([0.01]), pinned, 1e-7, 30, full_bending=True,
                              rest_bending=rest_bending)  # fmt: skip
        x, vel = x0.copy(), np.zeros_like(x0)
        far = np.array([[[50.0, 50.0, 50.0], [50.0, 50.1, 50.0]]])
        for _ in range(20):
            x, vel = cloth.step(x, vel, x0[pinned], far, far, 0.01)
        return x

    saved = implicit.GRAVITY.copy()
    implicit.GRAVITY[:] = 0.0  # the module's constant, put back below
    try:
        flat = run(v, False)
        held = run(v, True)
        turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        turned = v @ turn.T
        held_turned = run(turned, True)
    finally:
        implicit.GRAVITY[:] = saved
    assert np.abs(held - v).max() < 1e-6
    assert np.abs(held_turned - turned).max() < 1e-6
    assert np.abs(flat - v).max() > 1e-2


def test_with_bendings_whole_hessian_a_step_meets_its_tolerance_at_its_solution():
    # A curved sheet held along its middle, bending toward its rest shape, falls for 10 steps
    # to 0.3 mm rms (quick's tolerance). With bending's diagonal alone in the matrix the Newton
    # updates shrink long before the bends have settled, and the steps stop 5 cm from the
    # steps solved to 1e-12; with the whole Hessian they stop within the tolerance of them.
    v, f, i = _curved_sheet()
    pinned = i[:, 3]
    rest = cloth_rest(v, f, 0.15, 2e-3)
    far = np.array([[[50.0, 50.0, 50.0], [50.0, 50.1, 50.0]]])

    def run(full_bending, tol, iterations):
        cloth = ImplicitCloth(rest, 5e3, 1e4, np.full(len(v), 0.004), np.zeros(1),
                              np.array([0.01]), pinned, tol, iterations, "rms",
                              full_bending=full_bending, rest_bending=True)  # fmt: skip
        x, vel = v.copy(), np.zeros_like(v)
        for _ in range(10):
            x, vel = cloth.step(x, vel, v[pinned], far, far, 1.0 / 60.0)
        return x

    solved = run(True, 1e-12, 200)
    rms = {full: np.sqrt(((run(full, 3e-4, 16) - solved) ** 2).sum(1).mean()) for full in (0, 1)}
    assert rms[1] < 3e-4
    assert rms[0] > 100 * rms[1]


def test_the_bodys_push_stops_growing_past_the_release_depth():
    v, f, i = _sheet(4, 0.3)
    ends = np.array([[[-0.1, 0.98, 0.1], [0.4, 0.98, 0.1]]])
    held = ImplicitCloth(cloth_rest(v, f, 0.15, 0.0), 5e3, 1e4, np.full(len(v), 0.004),
                         np.zeros(1), np.array([0.05]), i[0], 1e-5, 8)  # fmt: skip
    freed = ImplicitCloth(held.rest, 5e3, 1e4, np.full(len(v), 0.004), np.zeros(1),
                          np.array([0.05]), i[0], 1e-5, 8, release=0.01)  # fmt: skip
    y = v.copy()  # one row over the bar's axis, 34, 19, 7 and 2 mm past the margin
    y[i[1], 1] = 0.98 + np.array([0.02, 0.035, 0.047, 0.052])
    pairs = held._pairs([y], [ends], 0.0)
    d = segment_gaps(y, ends)[:, 0]
    pen = 0.054 - d
    assert pen.max() > 0.03
    push = np.linalg.norm(freed._contact(y, ends, pairs, True)[1], axis=1)
    full = np.linalg.norm(held._contact(y, ends, pairs, True)[1], axis=1)
    deep, shallow = pen > 0.01, (pen > 0) & (pen < 0.01)
    assert np.allclose(push[deep], 1e4 * 0.01)
    assert np.allclose(push[shallow], full[shallow])
    assert (full[deep] > push[deep] + 1.0).all()
    # the energy is that push's: continuous, linear past the depth
    e = freed._contact(y, ends, pairs, False, False)[0]
    expect = 0.5 * 1e4 * (np.minimum(pen, 0.01) * (2 * pen - np.minimum(pen, 0.01)))[pen > 0].sum()
    assert e == pytest.approx(expect, rel=1e-9)


def _fast_kick(frames: int = 16, fps: float = 30.0, peak: float = 1.6, rise: int = 4):
    """The mannequin still, then its left thigh kicked forward ``peak`` radians in ``rise``
    frames (about 12 rad/s): a limb that crosses a knee-length skirt's hem within a step."""
    from core.body.shape import mannequin_skeleton
    from core.motion.motion import Motion
    from core.skeleton import rotation_about

    sk = mannequin_skeleton(BodyShape())
    rot = np.broadcast_to(np.eye(3), (frames, sk.num_joints, 3, 3)).copy()
    angle = np.clip((np.arange(frames) - 4) / rise, 0, 1) * peak
    rot[:, sk.index("LeftUpLeg")] = rotation_about([1, 0, 0], -angle)
    root = np.broadcast_to(sk.rest_positions()[0], (frames, 3)).copy()
    return Motion(sk, rot.astype(np.float32), root.astype(np.float32), fps, name="fast-kick")


def test_a_frame_a_limb_went_through_is_run_again_finer():
    """At one step a frame the kick carries the layered skirt's front 48 mm into the thigh
    (the push stops growing past ``layer_release``); re-run with twice the steps where that
    happened (``retry_depth``), no vertex is left inside, and only that frame pays."""
    skirt = frustum_skirt(24, 10, hem_height=0.30)
    layers = np.full(skirt.num_vertices, 0.03)
    cfg = replace(FAST, substeps=1, iterations=16, implicit_tol=3e-4, implicit_norm="rms",
                  settle_s=0.3)  # fmt: skip
    before, through = simulate(skirt, _fast_kick(), BodyShape(), replace(cfg, retry_depth=None),
                               thickness=layers)  # fmt: skip
    cache, kept = simulate(skirt, _fast_kick(), BodyShape(), cfg, thickness=layers)
    assert through.penetration_max_mm > 30.0 and not through.refined_frames
    assert kept.penetration_max_mm < 5.0 and kept.strain_max < 0.1 < through.strain_max
    assert 1 <= len(kept.refined_frames) <= 2 and not kept.retried_frames
    # frames before the kick are the same steps, to the bit
    first = min(kept.refined_frames)
    assert np.array_equal(cache.positions[:first], before.positions[:first])
    with pytest.raises(InputError, match="retry_depth"):
        replace(cfg, retry_depth=-1.0)
