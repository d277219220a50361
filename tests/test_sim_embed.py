"""Driving a detailed garment by its proxy: exact at rest, rigid motions carried exactly."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InputError
from core.sim.embed import drive, embed
from core.skeleton import rotation_about
from tests.conftest import assert_close
from tests.sim_helpers import frustum_skirt


@pytest.fixture(scope="module")
def skirts():
    proxy = frustum_skirt()
    rng = np.random.default_rng(3)
    # A "detailed" garment: the proxy's points pushed in and out along the radius (layers),
    # plus jitter, like stacked tiers and ruffles around the outer surface.
    pts = proxy.vertices[rng.integers(0, proxy.num_vertices, 800)].astype(np.float64)
    radial = pts * np.array([1.0, 0.0, 1.0])
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    pts += radial * rng.uniform(-0.05, 0.01, (len(pts), 1)) + rng.normal(0, 0.003, pts.shape)
    return proxy, pts.astype(np.float32)


def test_rest_pose_reproduces_the_target(skirts):
    proxy, target = skirts
    e = embed(target, proxy.vertices, proxy.faces)
    out = drive(e, proxy.vertices[None])
    assert_close(out[0], target, atol=1e-5, what="target at rest")


def test_rigid_motion_of_the_proxy_moves_the_target_rigidly(skirts):
    proxy, target = skirts
    e = embed(target, proxy.vertices, proxy.faces)
    r = rotation_about([0.3, 1.0, 0.2], 1.1)
    shift = np.array([0.5, -0.2, 2.0])
    moved = proxy.vertices @ r.T + shift
    out = drive(e, np.stack([proxy.vertices, moved]))
    assert_close(out[1], target @ r.T + shift, atol=1e-4, what="rigidly moved target")
    assert np.isfinite(out).all() and out.dtype == np.float32


def test_bad_input_is_refused(skirts):
    proxy, target = skirts
    with pytest.raises(InputError, match="target"):
        embed(np.full((3, 3), np.nan), proxy.vertices, proxy.faces)
    e = embed(target, proxy.vertices, proxy.faces)
    with pytest.raises(InputError, match="proxy positions"):
        drive(e, proxy.vertices[None, :5])


def test_a_saved_embedding_drives_the_target_to_the_bit(tmp_path):
    from core.sim.embed import load_embedding, save_embedding

    proxy = frustum_skirt()
    vertices, faces = layered_target()
    e = embed(vertices, proxy.vertices, proxy.faces, target_faces=faces)
    save_embedding(tmp_path / "e.npz", e)
    back = load_embedding(tmp_path / "e.npz")
    moved = proxy.vertices[None] * np.array([[[1.1, 0.9, 1.0]]], np.float32)
    frames = np.concatenate([proxy.vertices[None], moved])
    assert np.array_equal(drive(back, frames), drive(e, frames))
    assert (back.weight != e.weight).nnz == 0 and back.weight.shape == e.weight.shape
    assert np.array_equal(back.anchor, e.anchor) and back.anchor.dtype == e.anchor.dtype
    with pytest.raises(InputError, match="no such embedding file") as err:
        load_embedding(tmp_path / "none.npz")
    assert "none.npz" in str(err.value)
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="not an embedding") as err:
        load_embedding(tmp_path / "bad.npz")
    assert "bad.npz" in str(err.value)


def layered_target(around: int = 72, rings: int = 34) -> tuple[np.ndarray, np.ndarray]:
    """A detailed two-tier skirt around the 24 x 12 proxy: a fine inner layer on the proxy and
    an outer layer 2 cm outside it (one mesh, two pieces)."""
    fine = frustum_skirt(around, rings)
    outer = fine.vertices.astype(np.float64).copy()
    r = np.linalg.norm(outer[:, [0, 2]], axis=1, keepdims=True)
    outer[:, [0, 2]] *= (r + 0.02) / r
    vertices = np.concatenate([fine.vertices, outer]).astype(np.float32)
    return vertices, np.concatenate([fine.faces, fine.faces + fine.num_vertices])


def test_embedded_target_does_not_tear_on_a_simulated_spin():
    from core.body.shape import BodyShape
    from core.sim.config import SimConfig
    from core.sim.embed import strain_stats
    from core.sim.simulate import simulate
    from tests.sim_helpers import spin_motion

    proxy = frustum_skirt(24, 12)
    config = SimConfig(substeps=2, iterations=4, transition_s=0.2, settle_s=0.2)
    cache, _ = simulate(proxy, spin_motion(12, turns_per_s=1.0), BodyShape(), config)
    vertices, faces = layered_target()
    e = embed(vertices, proxy.vertices, proxy.faces, target_faces=faces)
    moved = drive(e, cache.positions)
    assert np.linalg.norm(moved[-1] - vertices, axis=1).max() > 0.02  # it did move
    stats = strain_stats(moved, vertices, faces)
    assert stats.stretch_p99 <= 0.1 and stats.stretch_max <= 0.3, stats
    assert stats.torn_edges == 0


def test_strain_stats_measure_stretch_compression_and_tears():
    from core.sim.embed import strain_stats

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64)
    f = np.array([[0, 1, 2]])
    moved = v.copy()
    moved[1, 0] = 2.5  # edge 0-1 stretched by 1.5: a tear
    moved[2, 1] = 0.5  # edge 0-2 compressed by half; edge 1-2 stretched by 0.80
    s = strain_stats(np.stack([v, moved]), v, f)
    assert np.isclose(s.stretch_max, 1.5) and np.isclose(s.compression_max, 0.5)
    assert s.torn_edges == 1


def test_contact_keeps_an_inner_layer_out_of_the_body_without_tearing_it():
    from core.body.colliders import penetration_depths
    from core.sim.embed import BodyContact, strain_stats

    proxy = frustum_skirt(48, 20)
    inner = proxy.vertices.astype(np.float64).copy()  # a layer 3 cm inside the proxy
    r = np.linalg.norm(inner[:, [0, 2]], axis=1, keepdims=True)
    inner[:, [0, 2]] *= (r - 0.03) / r
    faces = proxy.faces
    e = embed(inner, proxy.vertices, proxy.faces, target_faces=faces)
    # A thigh-like capsule pushing out along +X at mid-skirt: into the inner layer by up to
    # 2 cm, short of the proxy by 1 cm.
    y = float(np.median(proxy.vertices[:, 1]))
    ring = np.abs(proxy.vertices[:, 1] - y) < 0.03
    r_mid = float(np.linalg.norm(proxy.vertices[ring][:, [0, 2]], axis=1).min())
    ends = np.array([[[[0.0, y, 0.0], [r_mid - 0.06, y, 0.0]]]])
    radii = np.array([0.05])
    frames = proxy.vertices[None].astype(np.float64)
    free = drive(e, frames)
    assert penetration_depths(free, ends, radii).max() > 0.01  # the layer is inside
    kept = drive(e, frames, BodyContact(ends, radii))
    assert penetration_depths(kept, ends, radii).max() <= 1e-6
    stats = strain_stats(kept, inner, faces)
    assert stats.torn_edges == 0 and stats.stretch_max <= 0.3, stats
    far = np.linalg.norm(inner - [r_mid, y, 0.0], axis=1) > 0.25
    assert far.any() and np.array_equal(kept[0, far], free[0, far])  # only the contact moved
    with pytest.raises(InputError, match="contact capsules"):
        drive(e, np.concatenate([frames, frames]), BodyContact(ends, radii))


def test_shortening_moves_only_the_ends_the_contact_step_may_move():
    from core.strain import shorten_edges as _shorten

    x = np.array([[0.0, 0, 0], [2.0, 0, 0], [4.0, 0, 0], [5.0, 0, 0]])
    edges = np.array([[0, 1], [1, 2], [2, 3]])
    limit = np.array([1.0, 2.0, 0.5])
    movable = np.array([False, True, True, True])
    hit = _shorten(x, edges, limit, movable)
    # 0-1: the fixed end stays, the other takes the whole correction; 1-2 is at its limit;
    # 2-3: both ends movable, each moves half
    np.testing.assert_allclose(x[:, 0], [0.0, 1.0, 4.25, 4.75])
    assert sorted(hit.tolist()) == [1, 2, 3]


def test_limit_stretch_shortens_each_frame_to_its_limit_and_leaves_the_rest():
    from core.strain import limit_stretch, stretch_limit

    rest = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.0, 1.0, 0]])
    faces = np.array([[0, 1, 2]])
    s = stretch_limit(rest, faces, 0.1, 1)
    one = rest.copy()
    one[1, 0] = 1.5  # edge 0-1 at 1.5 against 1.1; edge 1-2 stretched too
    two = rest * 1.05  # within the limit: untouched
    out = limit_stretch(np.stack([one, two]), s)
    first = limit_stretch(one, s)  # one frame alone: the same
    np.testing.assert_array_equal(out[0], first)
    np.testing.assert_array_equal(out[1], two)
    # one sweep: vertex 0 moves half of edge 0-1's excess; vertex 1 the mean of its two edges'
    np.testing.assert_allclose(first[0], [0.2, 0.0, 0.0])
    assert np.linalg.norm(first[1] - first[0]) < 1.5
    held = limit_stretch(one, stretch_limit(rest, faces, 0.1, 200))
    length = np.linalg.norm(held[faces[0, [1, 2, 2]]] - held[faces[0, [0, 1, 0]]], axis=1)
    rest_length = np.array([1.0, np.sqrt(2.0), 1.0])
    assert (length <= 1.1 * rest_length + 1e-6).all()
    with pytest.raises(InputError):
        stretch_limit(rest, faces, -0.1, 5)
