"""``benchmarks/sim_bands.py``: a project's simulated proxies measured against the body again
from their caches, beside the figures their reports hold."""

from __future__ import annotations

import json
from functools import partial

import numpy as np

from tests.conftest import run_benchmark

_run = partial(run_benchmark, "sim_bands.py")


def test_sim_bands_rows_match_the_reports_the_demo_wrote(smoke_project):
    out = _run(smoke_project, "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["command"] == "python benchmarks/sim_bands.py PROJECT"
    rows = {r["clip"]: r for r in result["rows"]}
    sims = sorted(p.name[: -len("-proxy")] for p in smoke_project.glob("sim/*-proxy"))
    assert sorted(rows) == sims and sims
    for clip, r in rows.items():
        # the code that simulated the smoke project is this code: the figures agree, the
        # pelvis read off the motion's joints within 2 mm of the body's as simulated
        for name in ("hem_radius_ratio", "waistband_rise_max_mm", "hem_rise_end_mm"):
            now, then = r[name], r[f"report_{name}"]
            assert (now is None) == (then is None), (clip, name)
            if now is not None:
                assert np.isclose(now, then, rtol=0.02, atol=3.0), (clip, name, now, then)
        assert 0.0 <= r["end_tilt_deg"] < 180.0 and r["end_hips_height"] > 0.0
    table = _run(smoke_project, "--clip", sims[0])
    assert table.returncode == 0, table.stderr
    lines = table.stdout.strip().splitlines()
    assert lines[0].startswith("| clip | hem ratio: report / now |") and len(lines) == 3
    assert lines[2].startswith(f"| {sims[0]} |")
    bad = _run(smoke_project, "--clip", "no-such-clip")
    assert bad.returncode == 2 and "no simulated proxy for no-such-clip" in bad.stderr
