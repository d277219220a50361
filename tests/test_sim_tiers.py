"""The detailed target's tiers simulated on its embedded motion (core.sim.tiers), and the
implicit solver's pieces they need (contact planes, bending's whole Hessian)."""

from __future__ import annotations

import numpy as np
import pytest

from core.body.shape import BodyShape
from core.errors import InputError
from core.sim.implicit import ImplicitCloth, cloth_rest
from core.sim.tiers import (
    TierConfig,
    distances,
    find_tiers,
    layer_crossings,
    simulate_tiers,
)
from templates.garments import make_garment

FPS = 30.0


@pytest.fixture(scope="module")
def skirt():
    """The built-in multilayer skirt at 25 mm (the smoke preset's), and its tiers."""
    mesh = make_garment("multilayer-skirt", 25.0, BodyShape(), 0)
    return mesh, find_tiers(mesh.vertices, mesh.faces, BodyShape())


def _far_body(frames: int):
    """One small capsule far below the garment: no body contact."""
    ends = np.zeros((frames, 1, 2, 3))
    ends[:, 0, 0] = [0.0, -5.0, 0.0]
    ends[:, 0, 1] = [0.0, -5.1, 0.0]
    return ends, np.array([0.01])


def test_the_tiers_are_the_skirts_frills_hanging_from_a_band_along_their_top(skirt):
    mesh, tiers = skirt
    assert tiers.pieces == 3  # one frill at each layer's hem
    y = mesh.vertices[:, 1]
    # the frills hang below the waist; the layers and the waistband stay embedded
    assert y[tiers.free].max() < y.max() - 0.2
    assert len(tiers.free) + len(tiers.beneath) == mesh.num_vertices
    assert not np.intersect1d(tiers.free, tiers.beneath).size
    seam = mesh.vertices[tiers.free[tiers.pinned]]
    # the seam is each frill's top band, a small part of it
    assert 0.05 < len(tiers.pinned) / len(tiers.free) < 0.4
    assert seam[:, 1].min() > y[tiers.free].min() + 0.03
    assert (np.diff(tiers.pinned) > 0).all()
    assert tiers.faces.max() < len(tiers.free)


def test_a_garment_without_loose_pieces_stays_embedded():
    mesh = make_garment("long-skirt", 25.0, BodyShape(), 0)
    tiers = find_tiers(mesh.vertices, mesh.faces, BodyShape())
    assert tiers.pieces == 0 and not len(tiers.free)
    frames = np.repeat(mesh.vertices[None], 3, 0)
    ends, radii = _far_body(3)
    out, run = simulate_tiers(frames, mesh.faces, mesh.vertices, tiers, ends, radii, FPS)
    np.testing.assert_array_equal(out, frames)
    assert run.steps == 0


def test_at_rest_the_tiers_hang_where_they_are_and_the_seams_follow_exactly(skirt):
    mesh, tiers = skirt
    frames = np.repeat(mesh.vertices[None].astype(np.float64), 15, 0)
    ends, radii = _far_body(15)
    out, run = simulate_tiers(frames, mesh.faces, mesh.vertices, tiers, ends, radii, FPS)
    assert np.isfinite(out).all()
    seam = tiers.free[tiers.pinned]
    np.testing.assert_allclose(out[:, seam], frames[:, seam], atol=1e-6)
    # the rest of the garment is the embedded one, untouched
    np.testing.assert_array_equal(out[:, tiers.beneath], frames[:, tiers.beneath])
    # the frills settle under gravity by millimetres, not centimetres
    assert distances(out, frames, tiers.free)["p95_mm"] < 10.0
    assert run.newton_mean >= 1


def test_a_skirt_that_stops_short_leaves_its_tiers_swinging_on_then_settling(skirt):
    """Moving at constant speed the tiers hang as at rest (no frame is special); when the
    skirt stops, they swing on in the direction it moved, and the damping settles them."""
    mesh, tiers = skirt
    n_move, n_stop = 20, 45
    speed = 0.6  # m/s along x
    t = np.arange(n_move + n_stop)
    shift = speed * np.minimum(t, n_move - 1) / FPS
    frames = mesh.vertices[None].astype(np.float64) + shift[:, None, None] * [1.0, 0.0, 0.0]
    ends, radii = _far_body(len(t))
    out, _ = simulate_tiers(frames, mesh.faces, mesh.vertices, tiers, ends, radii, FPS)
    lag = (out - frames)[:, tiers.free, 0].mean(1)  # the tiers' mean x offset per frame
    still = np.repeat(mesh.vertices[None].astype(np.float64), len(t), 0)
    rest, _ = simulate_tiers(still, mesh.faces, mesh.vertices, tiers, ends, radii, FPS)
    rest_lag = (rest - still)[:, tiers.free, 0].mean(1)
    moving = lag[5:n_move] - rest_lag[5:n_move]
    assert np.abs(moving).max() < 1e-3  # in uniform motion as at rest (to a millimetre)
    after = lag[n_move:] - rest_lag[n_move:]
    assert after[:8].max() > 2e-3  # they swing on forward by millimetres
    assert np.abs(after[-5:]).max() < 0.3 * after[:8].max()  # and settle


def test_the_floor_nudge_moves_the_start_and_is_seeded(skirt):
    mesh, tiers = skirt
    frames = np.repeat(mesh.vertices[None].astype(np.float64), 4, 0)
    ends, radii = _far_body(4)
    args = (mesh.faces, mesh.vertices, tiers, ends, radii, FPS)
    nudged = TierConfig(perturbation=1e-5, seed=1)
    a, _ = simulate_tiers(frames, *args, nudged)
    b, _ = simulate_tiers(frames, *args, nudged)
    c, _ = simulate_tiers(frames, *args)
    np.testing.assert_array_equal(a, b)
    assert 0 < distances(a, c, tiers.free)["mean_mm"] < 1.0


def test_layer_crossings_of_the_rest_garment_are_none(skirt):
    mesh, tiers = skirt
    frames = np.repeat(mesh.vertices[None], 2, 0)
    fraction, deepest = layer_crossings(frames, mesh.vertices, tiers)
    assert fraction == 0.0 and deepest == 0.0


def test_layer_crossings_see_tiers_put_2_mm_behind_the_cloth_beneath(skirt):
    """Every tier vertex that takes the layer contact, put 2 mm behind its nearest vertex of
    the cloth beneath (along that vertex's normal): all of them cross, 2 mm deep."""
    from scipy.spatial import cKDTree

    from core.sim.tiers import _Beneath, _contact_mask

    mesh, tiers = skirt
    rest = mesh.vertices.astype(np.float64)
    pts, normals = _Beneath(rest, tiers).at(rest)
    mask = _contact_mask(rest[tiers.free], tiers, TierConfig())
    assert mask.sum() > 100
    moved = rest.copy()
    chosen = tiers.free[mask]
    _, j = cKDTree(pts).query(rest[chosen])
    moved[chosen] = pts[j] - 0.002 * normals[j]
    fraction, deepest = layer_crossings(moved[None], rest, tiers)
    assert fraction > 0.95
    assert deepest == pytest.approx(0.002, abs=2e-4)


def test_the_config_rejects_bad_values():
    with pytest.raises(InputError):
        TierConfig(substeps=0)
    with pytest.raises(InputError):
        TierConfig(fabric="tinfoil")
    with pytest.raises(InputError):
        TierConfig(damping=-1.0)


def test_simulate_tiers_names_the_shapes_it_needs(skirt):
    mesh, tiers = skirt
    ends, radii = _far_body(3)
    with pytest.raises(InputError, match="tiers need"):
        simulate_tiers(mesh.vertices[None], mesh.faces, mesh.vertices, tiers, ends, radii, FPS)


def _sheet(n: int = 6, h: float = 0.02):
    """A flat n x n sheet in the xz plane at height 1 (vertices, faces)."""
    g = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2) * h
    v = np.column_stack([g[:, 0], np.ones(len(g)), g[:, 1]])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = (
        idx[:-1, :-1].ravel(),
        idx[1:, :-1].ravel(),
        idx[:-1, 1:].ravel(),
        idx[1:, 1:].ravel(),
    )
    return v, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def _cloth(v, f, full_bending=False, tol=1e-9, iterations=50):
    rest = cloth_rest(v, f, 0.15, 2e-5)
    return ImplicitCloth(
        rest, 5e3, 1e4, np.full(len(v), 0.004), np.zeros(1), np.array([0.01]),
        np.array([0]), tol, iterations, "max", full_bending=full_bending,
    )  # fmt: skip


def test_a_contact_plane_holds_falling_cloth_at_its_margin():
    v, f = _sheet()
    cloth = _cloth(v, f)
    far = np.array([[[0.0, -5.0, 0.0], [0.0, -5.1, 0.0]]])
    x, vel = v.astype(np.float64), np.zeros_like(v, dtype=np.float64)
    free = np.arange(1, len(v))
    for _ in range(40):  # falls onto the plane y = 0.99 (margin 2 mm above it)
        planes = (
            free,
            np.tile([0.0, 0.99, 0.0], (len(free), 1)),
            np.tile([0.0, 1.0, 0.0], (len(free), 1)),
            0.002,
        )
        x, vel = cloth.step(x, vel, v[:1], far, far, 1 / 60, None, planes)
    assert np.isfinite(x).all()
    # a penalty: the weight of a few grams sinks it micrometres under the margin, no more
    assert x[free, 1].min() > 0.99 + 0.002 - 1e-4
    assert x[free, 1].max() < 0.99 + 0.002 + 0.02


def test_bendings_whole_hessian_converges_where_its_diagonal_alone_crawls():
    """A sheet hanging from one corner, one step: with bending's whole Hessian Newton
    converges to 1e-10 m in a few dozen iterations; with its diagonal alone (the proxy's
    matrix) 200 iterations do not reach it, though they come within a millimetre."""
    v, f = _sheet(8)
    x0 = v.astype(np.float64)
    vel = np.zeros_like(x0)
    far = np.array([[[0.0, -5.0, 0.0], [0.0, -5.1, 0.0]]])
    out = {}
    for full in (False, True):
        cloth = _cloth(v, f, full_bending=full, tol=1e-10, iterations=200)
        y, _ = cloth.step(x0, vel, v[:1], far, far, 1 / 30)
        out[full] = (y, cloth.newton_iterations[-1])
    assert out[True][1] < 50
    assert out[False][1] == 200
    assert np.abs(out[True][0] - out[False][0]).max() < 1e-3
