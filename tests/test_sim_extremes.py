"""Stability at the extremes: fast spins, jumps, 24 and 120 fps, light and heavy fabric, a large
body. Each case must finish (retrying frames if it needs to) with a finite cache, strain below
the blow-up level and the skirt still on the body. Slow on CPU (about a minute per case)."""

from __future__ import annotations

import numpy as np
import pytest

from core.body.shape import BodyShape
from core.sim.config import SimConfig
from core.sim.simulate import simulate
from tests.sim_helpers import frustum_skirt

CASES = {
    "twirl-24fps-silk": ("twirl", 24.0, "silk", BodyShape()),
    "jump-120fps-denim": ("jump", 120.0, "denim", BodyShape()),
    "dance-30fps-cotton-large-body": (
        "dance", 30.0, "cotton", BodyShape(height=1.95, waist=1.0, hip=1.25, chest=1.15, build=0.8)
    ),
}  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(CASES))
def test_extreme_motion_stays_sane(case):
    from core.motion.procedural import make_motion

    kind, fps, fabric, shape = CASES[case]
    frames = int(fps * 1.0)  # one second of the clip
    motion = make_motion(kind, frames, fps, 0, shape)
    skirt = frustum_skirt(32, 16, height=shape.height)
    if shape.hip > 1.0:  # widen the test skirt for the large body
        v = skirt.vertices.copy()
        v[:, [0, 2]] *= shape.hip / 0.96
        skirt = type(skirt)(v, skirt.faces)
    cfg = SimConfig(fabric=fabric, transition_s=0.5, settle_s=0.2)
    cache, report = simulate(skirt, motion, shape, cfg)
    assert np.isfinite(cache.positions).all()
    assert report.strain_max < cfg.blowup_strain * report.strain_limit
    # Still on the body: the waistband is within reach of the hips every frame.
    hips = motion.root_positions
    top = cache.positions[:, :32]
    reach = np.linalg.norm(top - hips[:, None], axis=-1).max()
    assert reach < 0.5, f"{case}: waistband {reach:.2f} m from the hips"
    print(case, report.as_dict())
