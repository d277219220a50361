"""``benchmarks/joint2coarse_stretch.py``: what each strain limit does to a project's
Joint2Coarse predictions."""

from __future__ import annotations

import json
from functools import partial

from tests.conftest import run_benchmark

_run = partial(run_benchmark, "joint2coarse_stretch.py")


def test_stretch_rows(smoke_project, tmp_path):
    out = _run(smoke_project, "--split", "test", "--limits", 0.0, 0.02, "--sweeps", 30, "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    raw, zero, two, sim = result["rows"]
    assert [r["name"] for r in result["rows"]] == [
        "as it comes", "limit 0, 30 sweeps", "limit 0.02, 30 sweeps", "simulation",
    ]  # fmt: skip
    assert raw["ms_per_frame"] is None and two["ms_per_frame"] > 0
    # a limit only shortens: the tighter, the less stretch
    assert zero["stretch_p99"] <= two["stretch_p99"] <= raw["stretch_p99"]
    assert two["stretch_max"] <= raw["stretch_max"]
    assert sim["error_mm"] is None and 0 <= sim["stretch_p99"] < 1
    assert result["command"].endswith("--split test --limits 0.0 0.02 --sweeps 30")
    text = _run(smoke_project, "--split", "test", "--limits", 0.02, "--sweeps", 5)
    assert text.returncode == 0 and "| limit 0.02, 5 sweeps |" in text.stdout
    bad = _run(tmp_path)
    assert bad.returncode == 2 and "no trained Joint2Coarse" in bad.stderr
