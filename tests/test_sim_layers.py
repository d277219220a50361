"""Garments of several stacked parts: layers pinned at one waist a few millimetres apart, loose
pieces (frills, sashes, bows) that no pin holds.

Two faults made every built-in multi-part garment blow up in the first step of the lead-in:
Style3D weighed a cloth-cloth contact among pinned (zero-mass) particles 0 / 0 (a NaN that its
global solve spread everywhere), and loose pieces hung from nothing. Contacts among kinematic
particles are now finite, the contact thickness stays below the templates' 4 mm gaps, and loose
pieces are sewn to the part they lie on (:func:`core.sim.pins.find_seams`).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from core.body.shape import BodyShape, mannequin_skeleton
from core.mesh import Mesh
from core.sim.config import SimConfig
from core.sim.pins import find_pins, find_seams
from tests.sim_helpers import frilled_skirt, spin_motion

#: Fast settings for tests: short lead-in, few steps.
FAST = SimConfig(substeps=2, iterations=4, transition_s=0.2, settle_s=0.2)


def _rigid(x: np.ndarray) -> np.ndarray:
    c, s = np.cos(0.7), np.sin(0.7)
    r = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return x @ r.T + np.array([0.3, -0.1, 0.2])


def test_loose_pieces_are_sewn_to_the_part_beside_them():
    shape = BodyShape()
    sk = mannequin_skeleton(shape)
    skirt, piece = frilled_skirt()
    # A far ring (2 m down): a loose piece with nothing within reach stays loose.
    ring = skirt.vertices[piece == 2] - np.float32([0, 2.0, 0])
    far_faces = skirt.faces[(piece == 2)[skirt.faces[:, 0]]] - (piece != 2).sum() + len(piece)
    mesh = Mesh(np.concatenate([skirt.vertices, ring]), np.concatenate([skirt.faces, far_faces]))
    pins = find_pins(mesh.vertices, mesh.faces, sk, 0.03, shape.height)
    assert set(piece[pins.indices[pins.indices < len(piece)]]) == {0, 1}  # both waists
    seams = find_seams(mesh.vertices, mesh.faces, pins.indices, 0.03)
    assert (seams.pieces, seams.loose) == (1, 1)
    frill = np.flatnonzero(piece == 2)
    top = frill[skirt.vertices[frill, 1] > skirt.vertices[frill, 1].max() - 1e-4]
    assert np.array_equal(seams.indices, top)  # the frill's top loop, every vertex of it
    assert (piece[seams.hosts] == 1).all()  # on the outer layer
    assert (np.abs(seams.normal_offset) < 0.012).all()
    # The seams sit exactly where the sewn vertices are, at rest and after a rigid motion.
    at_rest = seams.targets(mesh.vertices, mesh.faces)
    np.testing.assert_allclose(at_rest, mesh.vertices[seams.indices], atol=1e-6)
    moved = _rigid(mesh.vertices.astype(np.float64))
    np.testing.assert_allclose(seams.targets(moved, mesh.faces), moved[seams.indices], atol=1e-6)


def test_stacked_layers_and_a_frill_simulate():
    """Waists 2 mm apart (inside the contact thickness) gave NaN in the first step."""
    from core.sim.simulate import simulate

    skirt, piece = frilled_skirt()
    cache, report = simulate(skirt, spin_motion(6), BodyShape(), FAST)
    assert report.finite and np.isfinite(cache.positions).all()
    assert cache.params["sim"]["self_collision"] is True
    assert report.strain_max < report.strain_limit
    assert report.penetration_max_mm < 5.0
    assert cache.params["sewn_vertices"] == 48
    assert any("sewn by 48 vertices" in n for n in report.notes)
    # The frill stays where it was sewn: its distance to the outer layer as at rest.
    q = cache.positions
    rest = cKDTree(skirt.vertices[piece == 1]).query(skirt.vertices[piece == 2])[0]
    for t in range(len(q)):
        d = cKDTree(q[t][piece == 1]).query(q[t][piece == 2])[0]
        assert np.abs(d - rest).max() < 0.02, t


def _multi_part_case(name: str, res: float, frames: int, config: SimConfig):
    from core.motion.procedural import make_motion
    from core.sim.simulate import simulate
    from templates.garments import build_garment

    g = build_garment(name, res)
    cache, report = simulate(g.mesh, make_motion("dance", frames, 30, 0), config=config)
    assert report.finite and np.isfinite(cache.positions).all()
    # Nothing torn: stretch beyond the fabric's limit stays rare and local.
    assert report.strain_p99 < report.strain_limit
    assert report.strain_over_limit < 0.02
    assert report.penetration_p99_mm < 1.0
    # Loose pieces stay on the parts they are sewn to: no farther from them than at rest
    # plus a few centimetres
    m = g.mesh
    part = np.full(m.num_vertices, -1)
    fp = np.asarray(g.face_parts)
    for k in range(len(g.parts)):
        part[np.unique(m.faces[fp == k])] = k
    seams = find_seams(m.vertices, m.faces, np.asarray(cache.params["pinned_indices"]), 0.03)
    for k in np.unique(part[seams.indices]):
        host = np.unique(part[seams.hosts[part[seams.indices] == k]])
        rest = cKDTree(m.vertices[np.isin(part, host)]).query(m.vertices[part == k])[0]
        last = cache.positions[-1]
        now = cKDTree(last[np.isin(part, host)]).query(last[part == k])[0]
        # (the piece swings about its seam; fallen off, it would hang a tier lower, 10+ cm)
        assert now.max() < rest.max() + 0.04, g.parts[k]
    return report


def test_multilayer_skirt_starts_without_blowing_up():
    """The reported case: blew up at the lead-in at every quality."""
    short = SimConfig(substeps=2, iterations=8, transition_s=0.2, settle_s=0.1)
    report = _multi_part_case("multilayer-skirt", 25, 2, short)
    assert any("3 loose piece(s)" in n for n in report.notes)


@pytest.mark.slow
@pytest.mark.parametrize(
    "name,res",
    [("multilayer-skirt", 25), ("double-skirt", 22), ("tango-skirt", 22),
     ("pleated-skirt", 14), ("dress", 22)],
)  # fmt: skip
def test_detailed_garments_dance_at_draft_quality(name, res):
    _multi_part_case(name, res, 30, SimConfig(substeps=2, iterations=8))
