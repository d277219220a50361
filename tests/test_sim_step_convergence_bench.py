"""``benchmarks/sim_step_convergence.py``: one frame's solver steps re-run from the same state
at several iteration counts, against the step run to convergence."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from core.body.shape import BodyShape
from core.errors import InputError
from core.motion.procedural import make_motion
from tests.conftest import load_benchmark
from tests.sim_helpers import frustum_skirt

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "sim_step_convergence.py"


def _bench():
    return load_benchmark("sim_step_convergence.py")


def test_more_iterations_come_closer_to_the_converged_step():
    shape = BodyShape()
    motion = make_motion("walk", 4, 30.0, 0, shape)
    settings = [(0.0, 1), (0.0, 4), (0.0, 48), (0.9, 4)]
    out = _bench().measure(frustum_skirt(16, 6), motion, shape, 2, 2, settings, 48, 10)
    plain1, plain4, same, accelerated = out["rows"]
    assert out["moved_mm"] > 0
    # The reference's own setting, re-run from the same state, is the reference (CPU: serial).
    assert same["mean_mm"] == 0 and same["max_mm"] == 0
    assert plain1["mean_mm"] > plain4["mean_mm"] > 0
    assert accelerated["mean_mm"] < plain4["mean_mm"]
    assert [r["iterations"] for r in out["rows"]] == [1, 4, 48, 4]


def test_bad_settings_and_a_missing_garment_exit_with_a_message(tmp_path):
    shape = BodyShape()
    motion = make_motion("walk", 4, 30.0, 0, shape)
    bench = _bench()
    with pytest.raises(InputError, match="--frame must be in 1..2"):
        bench.measure(frustum_skirt(16, 6), motion, shape, 3, 2, [(0.0, 4)], 8, 10)
    with pytest.raises(InputError, match="at least 1"):
        bench.measure(frustum_skirt(16, 6), motion, shape, 1, 2, [(0.0, 0)], 8, 10)
    with pytest.raises(InputError, match="rhos"):
        bench.measure(frustum_skirt(16, 6), motion, shape, 1, 2, [(1.0, 4)], 8, 10)
    missing = tmp_path / "missing.obj"
    out = subprocess.run(
        [sys.executable, str(BENCH), "--garment", str(missing)], capture_output=True, text=True
    )
    assert out.returncode == 2 and "missing.obj" in out.stderr and out.stdout == ""
