"""``benchmarks/joint2coarse_validation.py``: the figures Joint2Coarse's choices are made on,
with training clips left out (``--without``), fitted on validation (``--fit-validation``) or
on a test motion (``--fit-test``) and mirrored (``--set mirror=true``)."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path

import pytest

from tests.conftest import run_benchmark

#: The paper model's stages cut short: these tests check the bench, not the model.
SHORT_STEPS = (
    "--set", "autoencoder_steps=20", "--set", "motion_steps=20", "--set", "finetune_steps=5",
)  # fmt: skip


_run = partial(run_benchmark, "joint2coarse_validation.py")


@pytest.fixture
def scratch_cache(tmp_path, monkeypatch) -> Path:
    """The scratch cache the bench simulates into (``XDG_CACHE_HOME``), empty, this test's own."""
    cache = tmp_path / "xdg-cache"
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
    return cache


def test_realisations(smoke_project, scratch_cache):
    """--realisations 1: every training clip trains on a second simulation of its motion too (the
    proxy moved 10 um), simulated into the scratch cache, not into the project."""
    cache = scratch_cache
    in_project = sorted(smoke_project.rglob("cache.npz"))
    out = _run(smoke_project, *SHORT_STEPS, "--realisations", "1", "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["realisations"] == 1 and result["realisations_from_first_mm"] > 0
    (motion,) = result["splits"]["validation"]
    assert result["runs"][0]["validation"]["motions"][motion]["mean_mm"] > 0
    assert len(list(cache.rglob("cache.npz"))) == len(result["train"])  # one more of each
    assert sorted(smoke_project.rglob("cache.npz")) == in_project
    bad = _run(smoke_project, "--realisations", "-1")
    assert bad.returncode == 2 and "--realisations -1 must be at least 0" in bad.stderr
    # --realisations-of: the further outcomes of some training clips only (from the cache)
    out = _run(
        smoke_project, *SHORT_STEPS, "--realisations", "1", "--realisations-of", "circle-*",
        "--json",
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    some = json.loads(out.stdout)
    assert some["realisations_of"] == ["circle-walk"]
    assert result["realisations_of"] == result["train"]  # without it: every training clip
    assert some["realisations_from_first_mm"] > 0
    assert len(list(cache.rglob("cache.npz"))) == len(result["train"])  # nothing simulated
    alone = _run(smoke_project, "--realisations-of", "circle-*")
    assert alone.returncode == 2 and "needs --realisations" in alone.stderr
    none = _run(smoke_project, "--realisations", "1", "--realisations-of", "no-such-clip")
    assert none.returncode == 2 and "--realisations-of matches no training motion" in none.stderr


def test_without_and_fit_validation(smoke_project):
    out = _run(smoke_project, *SHORT_STEPS, "--without", "circle-*", "--json")
    assert out.returncode == 0, out.stderr
    left = json.loads(out.stdout)
    assert left["left_out"] == ["circle-walk"] and left["train"] == ["dance"]
    assert not left["fit_validation"]
    out = _run(smoke_project, *SHORT_STEPS, "--fit-validation", "--json")
    assert out.returncode == 0, out.stderr
    fitted = json.loads(out.stdout)
    assert fitted["fit_validation"] and fitted["left_out"] == []
    for result in (left, fitted):
        (motion,) = result["splits"]["validation"]
        assert result["runs"][0]["validation"]["motions"][motion]["mean_mm"] > 0
    # mirrored training clips: the smoke project's proxy is symmetric enough for its map
    out = _run(smoke_project, *SHORT_STEPS, "--set", "mirror=true", "--json")
    assert out.returncode == 0, out.stderr
    mirrored = json.loads(out.stdout)
    assert mirrored["config"]["mirror"] is True
    assert mirrored["runs"][0]["validation"]["mean_over_motions"]["mean_mm"] > 0
    nothing = _run(smoke_project, "--without", "no-such-clip")
    assert nothing.returncode == 2 and "matches no training motion" in nothing.stderr
    everything = _run(smoke_project, "--without", "*")
    assert everything.returncode == 2 and "leaves no training motion" in everything.stderr
    unknown = _run(smoke_project, "--train-on", "no-such-clip")
    assert unknown.returncode == 2 and "matches no validation motion" in unknown.stderr
    (motion,) = left["splits"]["validation"]  # the smoke preset's one validation motion
    moved = _run(smoke_project, "--train-on", motion)
    assert moved.returncode == 2 and "leaves no validation motion to score" in moved.stderr
    # a test motion trained on too (a diagnosis): scored with the test split, named as a fit
    (test_motion, *_) = [
        m for m in ("cmu-01_01", "twirl") if (smoke_project / "sim" / f"{m}-proxy").is_dir()
    ]
    out = _run(smoke_project, *SHORT_STEPS, "--fit-test", test_motion, "--json")
    assert out.returncode == 0, out.stderr
    fit_test = json.loads(out.stdout)
    assert (
        fit_test["trained_on_test"] == [test_motion] and test_motion in fit_test["splits"]["test"]
    )
    assert fit_test["runs"][0]["test"]["motions"][test_motion]["mean_mm"] > 0
    assert "trained_on_test" in left and left["trained_on_test"] == []
    no_test = _run(smoke_project, "--fit-test", "no-such-clip")
    assert no_test.returncode == 2 and "matches no test motion" in no_test.stderr
    bad = _run(smoke_project, "--distance-vertices", "0")
    assert bad.returncode == 2 and "--distance-vertices 0 must be at least 1" in bad.stderr
    short = _run(smoke_project, "--long-lags")  # the smoke preset's 34-frame window
    assert short.returncode == 2 and "--long-lags reads 32 samples back" in short.stderr


def test_train_extra(smoke_project, scratch_cache):
    """--train-extra squat:24: a procedural clip the project does not hold, made as a library clip
    and simulated into the scratch cache (not the project), trained on beside the library."""
    cache = scratch_cache
    in_project = sorted(smoke_project.rglob("cache.npz"))
    out = _run(smoke_project, *SHORT_STEPS, "--train-extra", "squat:24:1", "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["train_extra"] == ["extra-squat-1"]
    (motion,) = result["splits"]["validation"]
    assert result["runs"][0]["validation"]["motions"][motion]["mean_mm"] > 0
    assert len(list(cache.rglob("cache.npz"))) == 1
    assert sorted(smoke_project.rglob("cache.npz")) == in_project
    for bad, says in (("nothing:10", "KIND one of"), ("squat:x", "whole numbers")):
        refused = _run(smoke_project, "--train-extra", bad)
        assert refused.returncode == 2 and says in refused.stderr, refused.stderr
