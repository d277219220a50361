"""The loss logs of the training loops: CSV files whose first column is the step.

A resumed run drops the rows written after the checkpoint it starts from, so the log of an
interrupted-and-resumed run equals that of an uninterrupted one.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence

from core.fileio import atomic_path


def append_rows(path: str | os.PathLike, columns: Sequence[str], rows: Sequence[Sequence]) -> None:
    """Append ``rows`` to the log at ``path``, writing the header first when it is new."""
    if not rows:
        return
    new = not os.path.isfile(path)
    with open(path, "a", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        if new:
            w.writerow(columns)
        w.writerows(rows)


def truncate_rows(path: str | os.PathLike, columns: Sequence[str], step: int) -> None:
    """Keep only well-formed rows of steps ``<= step`` (atomically); no file, nothing to do."""
    if not os.path.isfile(path):
        return
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    keep = [r for r in rows[1:] if len(r) == len(columns) and r[0].isdigit()]
    keep = [r for r in keep if int(r[0]) <= step]
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(columns)
        w.writerows(keep)


def read_loss_log(path: str | os.PathLike) -> list[dict[str, float]]:
    """Rows of a loss log as dicts of floats, in file order.

    Cells that are not numbers (``off``, empty) are left out of their row; a row with no
    number at all is kept as an empty dict. A missing file raises ``FileNotFoundError``.
    """
    rows = []
    with open(path, newline="", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            parsed = {}
            for k, v in row.items():
                try:
                    parsed[k] = float(v)
                except (TypeError, ValueError):
                    continue
            rows.append(parsed)
    return rows
