"""``benchmarks/renderer_seeds.py``: the headline ratio, ours over DNR, at another training
seed, beside the project's own."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.renderer_seeds import ratios

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "renderer_seeds.py"


def test_ratios_pool_the_frames_of_a_protocol():
    """U pools its motions' frames (as the report does): ours 1, 3 and 2 against DNR's 2, 2, 2."""
    values = {
        "ours": {"a": np.array([1.0, 3.0]), "b": np.array([2.0]), "c": np.array([4.0])},
        "dnr": {"a": np.array([2.0, 2.0]), "b": np.array([2.0]), "c": np.array([8.0])},
    }
    r = ratios(values, {"U": ["a", "b"], "P": ["c"]})
    assert r["U"] == {"ours_mse": 2.0, "dnr_mse": 2.0, "ratio": 1.0}
    assert r["P"]["ratio"] == 0.5


def test_another_seed_beside_the_projects(smoke_project):
    out = subprocess.run(
        [sys.executable, str(BENCH), str(smoke_project), "--seeds", "1", "--json"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["command"] == "python benchmarks/renderer_seeds.py PROJECT --seeds 1"
    (run,) = result["runs"]
    assert run["seed"] == 1 and set(run["train_s"]) == {"ours", "dnr"}
    for name in ("U", "P"):
        r = run["ratios"][name]
        assert np.isclose(r["ratio"], r["ours_mse"] / r["dnr_mse"])
        spread = result["spread"][name]
        assert spread["seeds"] == [0, 1] and len(spread["ratios"]) == 2
        assert np.isclose(spread["range"], abs(spread["ratios"][1] - spread["ratios"][0]))
    # the project's own seed, read from its report, not retrained
    assert [(r["seed"], r["protocol"]) for r in result["rows"]] == [
        (0, "U"),
        (0, "P"),
        (1, "U"),
        (1, "P"),
    ]
    assert [(r["seed"], r["protocol"]) for r in result["rows"]] == [
        (0, "U"), (0, "P"), (1, "U"), (1, "P"),
    ]  # fmt: skip
    report = json.loads((smoke_project / "eval" / "report.json").read_text())
    assert result["project_seed"]["U"]["ratio"] == report["mse_masked_ratio_ours_to_dnr"]
