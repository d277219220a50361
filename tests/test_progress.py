"""The one time-left estimator (core.progress.StageEta) and the one loss-log reader."""

from __future__ import annotations

import pytest

from core.progress import StageEta
from training.csvlog import append_rows, read_loss_log


def test_equal_stages_with_progress_inside_a_stage():
    now = [0.0]
    eta = StageEta(2, clock=lambda: now[0])
    assert eta.seconds_left() is None and eta.progress == 0.0
    now[0] = 10.0
    eta.update(1, 2)
    assert eta.progress == pytest.approx(0.25)
    assert eta.seconds_left() == pytest.approx(30.0)  # 10 s for a quarter
    eta.stage_done()
    assert eta.progress == pytest.approx(0.5)
    assert eta.seconds_left() == pytest.approx(10.0)  # one stage in 10 s, one left


def test_costed_stages_follow_the_pace_of_the_stages_that_ran():
    now = [0.0]
    eta = StageEta([10.0, 30.0, 60.0, 100.0], lambda: now[0], default_pace=1.0, reused_below=0.1)
    assert eta.seconds_left() == pytest.approx(200.0)  # nominal pace before any stage ran
    for seconds in (0.5, 60.0, 120.0):  # a reused stage, then twice the expected pace
        now[0] += seconds
        eta.stage_done(seconds)
    assert eta.done == 3 and eta.total == 4
    assert eta.seconds_left() == pytest.approx(2.0 * 100.0)
    eta.stage_done(1.0)
    assert eta.progress == 1.0 and eta.seconds_left() == pytest.approx(0.0)


def test_read_loss_log_keeps_numbers_only(tmp_path):
    path = tmp_path / "loss.csv"
    append_rows(path, ["step", "loss_g", "vgg"], [[1, 0.5, "off"], [2, "nan", ""]])
    rows = read_loss_log(path)
    assert rows[0] == {"step": 1.0, "loss_g": 0.5}
    assert rows[1]["step"] == 2.0 and rows[1]["loss_g"] != rows[1]["loss_g"]  # NaN kept
    assert "vgg" not in rows[1]
    with pytest.raises(FileNotFoundError):
        read_loss_log(tmp_path / "missing.csv")


def test_stages_that_end_out_of_order_count_their_own_cost():
    """Two stages side by side, the costly one ending first: the pace is its own (1 s a unit),
    not the cheap one's cost over its seconds (which gave a run of 37 minutes a time left of
    over three hours)."""
    now = [0.0]
    eta = StageEta([1.0, 100.0, 10.0], lambda: now[0], default_pace=1.0)
    now[0] = 100.0
    eta.stage_done(100.0, index=1)
    assert eta.done == 1 and eta.seconds_left() == pytest.approx(11.0)
    assert eta.progress == pytest.approx(100.0 / 111.0)
    eta.stage_done(1.0)  # the first not done: index 0
    assert eta.seconds_left() == pytest.approx(10.0)
    with pytest.raises(ValueError, match="not one of"):
        eta.stage_done(1.0, index=1)  # done already
    eta.stage_done(10.0)
    assert eta.done == 3 and eta.seconds_left() == pytest.approx(0.0)
