"""The deviations from the paper and what each method got: computed from the resolved
configurations, in the smoke report, and the results page's copy of the quick preset's tables is
what the code computes today."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from core.errors import InputError
from pipeline.config import PRESETS
from pipeline.deviations import (
    deviations,
    deviations_markdown,
    from_json,
    method_budgets,
    methods_markdown,
)

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results.md"


def test_the_results_page_tables_are_the_quick_presets():
    """docs/results.md is generated from a quick project: when the preset changes, it must be
    made again (``dng demo --out PROJECT``, then ``dng report PROJECT --results
    docs/results.md``)."""
    text = RESULTS.read_text()
    quick = PRESETS["quick"]
    assert deviations_markdown(deviations(quick)) in text
    assert methods_markdown(method_budgets(quick)) in text


def test_rows_follow_the_settings():
    quick = PRESETS["quick"]
    parts = [d.part for d in deviations(quick)]
    assert parts.count("data") == 3  # frames, views, image size
    # the paper's sizes and weights leave only what no setting changes
    paper = [d.paper for d in deviations(PRESETS["paper"])]
    assert not any(
        p.startswith(("one 850", "10 random", "512 px", "neural texture")) for p in paper
    )
    assert "SPADE block's shortcut SPADE(I(Z))" in paper
    # full adversarial weights: the loss row goes; a simulated target changes the ground truth
    full = replace(quick, renderer_overrides={}, target_mode="simulate", sim_solver="style3d")
    rows = {d.paper: d.here for d in deviations(full)}
    assert "L1 10, perceptual 10, feature matching 5, GAN 0.5" not in rows
    assert rows["the detailed garment simulated (Marvelous Designer)"].startswith("simulated")
    # training on Joint2Coarse's prediction is a deviation; on the simulation it is none
    trained_on = "the renderer trains on the training motion's simulated coarse garment"
    assert "Joint2Coarse's prediction" in {d.paper: d.here for d in deviations(quick)}[trained_on]
    assert trained_on not in {d.paper for d in deviations(replace(quick, renderer_source="sim"))}
    # the proxy's layer thickness is named in the ground truth only when it is on
    truth = "the detailed garment simulated (Marvelous Designer)"
    layered = "kept off the body by the depth of the target's layers"
    assert layered in {d.paper: d.here for d in deviations(quick)}[truth]
    thin = replace(quick, layer_thickness=False)
    # the proxy's solver is named; the implicit one cannot simulate the target's layers
    assert "by Newton's method, 2 a frame" in {d.paper: d.here for d in deviations(quick)}[truth]
    assert "Style3D" in {d.paper: d.here for d in deviations(full)}[truth]
    with pytest.raises(InputError, match="sim_solver='style3d'"):
        replace(quick, target_mode="simulate")
    assert layered not in {d.paper: d.here for d in deviations(thin)}[truth]
    # ours' loss is named when it is the distance
    ours_row = "shape autoencoder + motion encoder"
    assert "each vertex's distance" in {d.paper: d.here for d in deviations(quick)}[ours_row]
    squared = replace(quick, joint2coarse_overrides={**quick.joint2coarse_overrides})
    squared.joint2coarse_overrides["residual_loss"] = "squared"
    assert "distance" not in {d.paper: d.here for d in deviations(squared)}[ours_row]
    # the no-motion ablation's input (the coverage mask) is named where it runs
    no_motion = "without motion features: the neural texture's sample alone"
    assert no_motion not in {d.paper for d in deviations(quick)}
    assert "coverage mask" in {d.paper: d.here for d in deviations(PRESETS["paper"])}[no_motion]


def test_methods_count_their_parameters():
    assert {m.method for m in method_budgets(PRESETS["quick"])} == {"ours", "pix2pix", "dnr"}
    with_gan = replace(PRESETS["quick"], baselines=("pix2pix", "dnr", "dnr-gan"))
    budgets = {m.method: m for m in method_budgets(with_gan)}
    assert budgets["ours"].texture == budgets["dnr"].texture  # the same texture capacity
    assert budgets["pix2pix"].texture == "-"
    assert all(m.parameters > 100_000 and m.steps == 600 for m in budgets.values())
    assert budgets["dnr"].parameters == budgets["dnr-gan"].parameters


def test_the_report_carries_both_tables(smoke_project):
    import json

    report = json.loads((smoke_project / "report.json").read_text())
    rows, methods = from_json(report["against_the_paper"])
    assert rows == deviations(PRESETS["smoke"])
    assert [m.method for m in methods] == ["ours", *PRESETS["smoke"].baselines]
    md = (smoke_project / "report.md").read_text()
    assert "## Deviations from the paper" in md and deviations_markdown(rows) in md
    assert "## What each method got" in md and methods_markdown(methods) in md
