"""Where a project's figures came from: the source commit, the machine and the date.

Read without running any program: the commit comes from the checkout's ``.git`` files, so a
project made from an installed copy (no checkout) records ``None``.
"""

from __future__ import annotations

import datetime
import os
import platform
from pathlib import Path

SOURCE_ROOT = Path(__file__).resolve().parents[1]


def _git_dir(root: Path) -> Path | None:
    dot = root / ".git"
    if dot.is_dir():
        return dot
    if dot.is_file():  # a worktree or submodule: "gitdir: PATH"
        text = dot.read_text(encoding="utf-8").strip()
        if text.startswith("gitdir:"):
            target = Path(text.split(":", 1)[1].strip())
            return target if target.is_absolute() else (root / target).resolve()
    return None


def source_commit(root: Path = SOURCE_ROOT) -> str | None:
    """The 40-hex commit the checkout at ``root`` stands on, or None (no checkout, unreadable)."""
    git = _git_dir(root)
    if git is None:
        return None
    try:
        head = (git / "HEAD").read_text(encoding="utf-8").strip()
        if not head.startswith("ref:"):
            return head or None
        ref = head.split(":", 1)[1].strip()
        loose = git / ref
        if loose.is_file():
            return loose.read_text(encoding="utf-8").strip() or None
        common = git / "commondir"
        base = (git / common.read_text().strip()).resolve() if common.is_file() else git
        if (base / ref).is_file():
            return (base / ref).read_text(encoding="utf-8").strip() or None
        packed = base / "packed-refs"
        if packed.is_file():
            for line in packed.read_text(encoding="utf-8").splitlines():
                parts = line.split()
                if len(parts) == 2 and parts[1] == ref:
                    return parts[0]
    except OSError:
        return None
    return None


def machine() -> dict:
    """The machine in a few words: OS, CPU model, core count, Python and PyTorch versions."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        import torch

        torch_version = torch.__version__
        cuda = torch.cuda.is_available()
    except ImportError:  # the record still says what it can
        torch_version, cuda = None, False
    return {
        "system": f"{platform.system()} {platform.release()}",
        "cpu": cpu,
        "cores": len(os.sched_getaffinity(0))
        if hasattr(os, "sched_getaffinity")
        else os.cpu_count(),
        "python": platform.python_version(),
        "torch": torch_version,
        "cuda": cuda,
    }


def provenance() -> dict:
    """``{"commit", "date", "machine"}`` for a report made now (date in UTC, ISO 8601)."""
    return {
        "commit": source_commit(),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": machine(),
    }
