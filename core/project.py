"""A garment project is one folder on disk; each stage writes there with the parameters that made it.

A stage is fresh when its record exists and its fingerprint (the stage's parameters plus the
content of its input files) is unchanged, so a rerun skips it. The record is written last, after
every output file has been written atomically: a stage killed half-way has no record and runs
again.

Layout::

    PROJECT/
      project.json            settings (what the GUI and the CLI edit)
      <stage>/                one folder per stage: its outputs
      <stage>/stage.json      the record: fingerprint, parameters, outputs, seconds
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from core.errors import InputError
from core.fileio import write_json

RECORD_NAME = "stage.json"
ATTEMPT_NAME = ".attempt.json"
SETTINGS_NAME = "project.json"


@dataclass(frozen=True)
class StageRecord:
    """What a finished stage left behind."""

    name: str
    fingerprint: str
    params: dict
    outputs: tuple[str, ...]
    seconds: float


def fingerprint(params: dict, inputs: Iterable[str | os.PathLike] = ()) -> str:
    """SHA-256 of the canonical JSON of ``params`` and the bytes of each input file.

    Input files are hashed by content, not by time stamp, so touching a file does not
    invalidate a stage but editing it does. A missing input is an ``InputError``.
    """
    h = hashlib.sha256(json.dumps(params, sort_keys=True, default=str).encode())
    for path in inputs:
        path = Path(path)
        if not path.is_file():
            raise InputError("input file missing", path)
        h.update(path.name.encode())
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


class Project:
    """Paths and stage records of one project folder."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)

    def stage_dir(self, stage: str) -> Path:
        return self.root / stage

    def path(self, stage: str, name: str) -> Path:
        return self.root / stage / name

    def record(self, stage: str) -> StageRecord | None:
        """The stage's record, or None when it never finished (or its record is unreadable)."""
        path = self.path(stage, RECORD_NAME)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            return StageRecord(
                name=data["name"],
                fingerprint=data["fingerprint"],
                params=data["params"],
                outputs=tuple(data["outputs"]),
                seconds=float(data["seconds"]),
            )
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def is_fresh(self, stage: str, fp: str) -> bool:
        """True when the stage finished with fingerprint ``fp`` and all its outputs exist."""
        rec = self.record(stage)
        return (
            rec is not None
            and rec.fingerprint == fp
            and all(self.path(stage, o).exists() for o in rec.outputs)
        )

    def run_stage(
        self,
        stage: str,
        params: dict,
        inputs: Iterable[str | os.PathLike],
        work: Callable[[Path], Iterable[str]],
        force: bool = False,
        resumable: Iterable[str] = (),
    ) -> tuple[StageRecord, bool]:
        """Run ``work(stage_dir) -> output names`` unless the stage is fresh.

        Returns the record and whether the work ran. ``work`` must write its files atomically.
        ``resumable`` names files (training checkpoints) that let an interrupted run of the same
        stage continue: they are kept when the last attempt had this fingerprint, and deleted
        when the parameters or inputs changed since (a checkpoint of other settings is stale).
        """
        fp = fingerprint(params, inputs)
        if not force and self.is_fresh(stage, fp):
            return self.record(stage), False  # type: ignore[return-value]
        out = self.stage_dir(stage)
        out.mkdir(parents=True, exist_ok=True)
        (out / RECORD_NAME).unlink(missing_ok=True)
        attempt = out / ATTEMPT_NAME
        try:
            same = json.loads(attempt.read_text(encoding="utf-8")).get("fingerprint") == fp
        except (OSError, ValueError, AttributeError):
            same = False
        if not same or force:
            for name in resumable:
                (out / name).unlink(missing_ok=True)
        write_json(attempt, {"fingerprint": fp})
        start = time.perf_counter()
        outputs = tuple(str(o) for o in work(out))
        missing = [o for o in outputs if not (out / o).exists()]
        if missing:
            raise RuntimeError(f"stage {stage} did not write {missing}")
        rec = StageRecord(stage, fp, params, outputs, time.perf_counter() - start)
        write_json(out / RECORD_NAME, rec.__dict__)
        return rec, True

    def settings(self) -> dict[str, Any]:
        """The project's settings (``project.json``), empty when there are none yet."""
        path = self.root / SETTINGS_NAME
        if not path.exists():
            return {}
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except ValueError as exc:
            raise InputError(f"malformed settings ({exc})", path) from None
        if not isinstance(data, dict):
            raise InputError("settings must be a JSON object", path)
        return data

    def save_settings(self, settings: dict[str, Any]) -> None:
        write_json(self.root / SETTINGS_NAME, settings)
