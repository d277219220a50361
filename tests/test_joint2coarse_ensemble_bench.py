"""``benchmarks/joint2coarse_ensemble.py``: Joint2Coarse's ensemble ratio per motion, as rows
the results page shows."""

from __future__ import annotations

import json
from functools import partial

import numpy as np

from pipeline.report import _bench_markdown
from tests.conftest import run_benchmark

_run = partial(run_benchmark, "joint2coarse_ensemble.py")


def test_ensemble_rows(smoke_project, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg-cache"))
    out = _run(smoke_project, "--motion", "walk", "--frames", 36, "--realisations", 2, "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    (row,) = result["rows"]
    assert row["motion"] == "walk" and row["frames"] == 36 and row["simulations"] == 3
    assert np.isclose(row["ensemble_ratio"], row["ours_mm"] / row["mean_of_others_mm"])
    assert result["mean_ratio"] == row["ensemble_ratio"]
    assert 0 <= row["stretch_p99_prediction"] < 10 and row["hem_radius_difference_mm"] >= 0
    assert "walk: " in out.stderr and "x (ours" in out.stderr
    command = "python benchmarks/joint2coarse_ensemble.py PROJECT --motion walk --frames 36"
    assert result["command"] == command + " --realisations 2"
    table = "\n".join(_bench_markdown("joint2coarse-ensemble", result))
    assert f"Made by `{command} --realisations 2`." in table
    assert "| motion | frames | simulations | ours_mm |" in table and "| walk | 36 | 3 |" in table
    bad = _run(smoke_project, "--motion", "walk", "--realisations", 1)
    assert bad.returncode == 2 and "needs at least 2" in bad.stderr
