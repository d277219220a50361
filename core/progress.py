"""Time left of a job made of stages: one estimator for the command line and the GUI."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence


class StageEta:
    """Time left of a job made of stages, at the pace of the work done so far.

    Parameters
    ----------
    costs : sequence of float, or int
        Expected cost of every stage in order (any unit: seconds, frames...); an int ``n``
        means ``n`` stages of cost 1.
    clock : callable returning seconds
    default_pace : float or None
        Seconds per unit of cost assumed before any work has been timed (1.0 when the costs are
        expected seconds); None: no estimate until then.
    reused_below : float
        A stage finished in under this fraction of its cost (in seconds at the default pace;
        e.g. reused from an earlier run) does not set the pace.

    The pace is the seconds of the timed stages (plus the current one, once it reports
    progress with :meth:`update`) over their cost; the time left is the remaining cost at that
    pace.
    """

    def __init__(
        self,
        costs: Sequence[float] | int,
        clock: Callable[[], float] = time.perf_counter,
        default_pace: float | None = None,
        reused_below: float = 0.0,
    ):
        n = costs if isinstance(costs, int) else None
        self.costs = [1.0] * max(1, n) if n is not None else [float(c) for c in costs]
        self.clock = clock
        self.default_pace = default_pace
        self.reused_below = reused_below
        self.start = self.stage_start = clock()
        self.finished: set[int] = set()  # stages done, by their index in ``costs``
        self.fraction = 0.0  # of the current stage
        self.ran_seconds = self.ran_cost = 0.0

    @property
    def total(self) -> int:
        """Number of stages."""
        return len(self.costs)

    @property
    def done(self) -> int:
        """Number of stages done."""
        return len(self.finished)

    def _current(self) -> int:
        """The first stage not done (``total`` when all are)."""
        return next((i for i in range(self.total) if i not in self.finished), self.total)

    def _current_cost(self) -> float:
        i = self._current()
        return self.costs[i] if i < self.total else 0.0

    def update(self, done: int, total: int) -> None:
        """Progress within the current stage: ``done`` of ``total`` units."""
        self.fraction = min(max(done / total, 0.0), 1.0) if total > 0 else 0.0

    def stage_done(self, seconds: float | None = None, index: int | None = None) -> None:
        """A stage finished, after ``seconds`` (default: since the previous one): the stage at
        ``index`` in ``costs`` (default: the first not done). Stages that run side by side end
        out of order: each counts its own cost."""
        now = self.clock()
        seconds = now - self.stage_start if seconds is None else seconds
        index = self._current() if index is None else index
        if not 0 <= index < self.total or index in self.finished:
            raise ValueError(f"stage {index} is not one of the {self.total} stages left")
        cost = self.costs[index]
        if seconds >= self.reused_below * cost:
            self.ran_seconds += seconds
            self.ran_cost += cost
        self.finished.add(index)
        self.fraction = 0.0
        self.stage_start = now

    @property
    def progress(self) -> float:
        """Overall fraction of the cost done, in [0, 1]."""
        total = sum(self.costs)
        done = sum(self.costs[i] for i in self.finished) + self.fraction * self._current_cost()
        return min(done / total, 1.0) if total > 0 else 1.0

    def seconds_left(self) -> float | None:
        """Seconds left at the pace so far; None before any pace is known."""
        seconds, cost = self.ran_seconds, self.ran_cost
        if self.fraction > 0.0:
            seconds += self.clock() - self.stage_start
            cost += self.fraction * self._current_cost()
        if cost > 0.0:
            pace = seconds / cost
        elif self.default_pace is not None:
            pace = self.default_pace
        else:
            return None
        left = sum(c for i, c in enumerate(self.costs) if i not in self.finished)
        return pace * (left - self.fraction * self._current_cost())
