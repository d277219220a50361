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
