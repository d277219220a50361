"""Run a command under a time limit; past it the command has hung, and what the process was doing
is written down: :func:`run_watched` fails the test with it, :func:`watch` returns it (for a
caller that adds what it knows, like the GUI tour fixture, before it fails)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

#: Seconds given to the process to write its stacks after SIGUSR1.
STACK_WAIT_S = 10.0
#: Characters of the log's tail (before the stacks) in the failure message.
LOG_TAIL = 3000


def watch(
    command: list[str],
    timeout_s: float,
    log_path: Path,
    watch_dir: Path | None = None,
    **popen_kwargs,
) -> tuple[int | None, str | None]:
    """Run ``command`` with stdout and stderr into ``log_path``: ``(exit status, None)``, or
    ``(None, report)`` when it has hung.

    Past ``timeout_s`` it has hung: the threads of the process (name, state, CPU seconds, from
    /proc), their native stacks (gdb), the Python stack of every thread (the process is sent
    SIGUSR1 and must have registered ``faulthandler`` for it: without that SIGUSR1 ends it), the
    newest files in ``watch_dir`` and the tail of the log make the report, also written beside
    the log (``NAME.hang.txt``); the process is killed.
    """
    log_path = Path(log_path)
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, **popen_kwargs)
        try:
            return proc.wait(timeout_s), None
        except subprocess.TimeoutExpired:
            report = _hang_report(proc, timeout_s, log_path, watch_dir)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    hang_file = log_path.with_name(log_path.name + ".hang.txt")
    hang_file.write_text(report)
    return None, f"{report}\n(saved in {hang_file})"


def run_watched(
    command: list[str],
    timeout_s: float,
    log_path: Path,
    watch_dir: Path | None = None,
    **popen_kwargs,
) -> int:
    """:func:`watch`, failing the test with the report when the command hung; its exit status
    otherwise."""
    code, hang = watch(command, timeout_s, log_path, watch_dir, **popen_kwargs)
    if hang is not None:
        pytest.fail(hang, pytrace=False)
    return code


def _hang_report(proc: subprocess.Popen, timeout_s: float, log_path: Path, watch_dir) -> str:
    """What a hung process was doing, in words (see :func:`run_watched`)."""
    threads = thread_states(proc.pid)
    native = native_stacks(proc.pid)
    before = log_path.stat().st_size
    proc.send_signal(signal.SIGUSR1)
    deadline = time.monotonic() + STACK_WAIT_S
    size = before
    while time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.5)
        now = log_path.stat().st_size
        if before < now == size:
            break  # written, and nothing more coming
        size = now
    with open(log_path, "rb") as f:
        head = f.read(before).decode(errors="replace")
        stacks = f.read().decode(errors="replace")
    if not stacks:
        ended = "it ended on SIGUSR1" if proc.poll() is not None else "still running"
        stacks = f"(none written; {ended}: does it register faulthandler for SIGUSR1?)"
    parts = [
        f"{' '.join(map(str, proc.args))}\nhung: no exit after {timeout_s:.0f} s (log: {log_path})",
        "threads (name, state, CPU s, kernel wait), busiest first:\n" + threads,
    ]
    if watch_dir is not None:
        parts.append(f"newest files in {watch_dir}:\n" + newest_files(Path(watch_dir)))
    parts.append("log tail:\n" + head[-LOG_TAIL:])
    parts.append("Python stacks (SIGUSR1):\n" + stacks)
    parts.append("native stacks (gdb):\n" + native)
    return "\n\n".join(parts)


def thread_states(pid: int, limit: int = 25) -> str:
    """One line per thread of process ``pid``: name, state, CPU seconds and kernel wait
    channel, busiest first (Linux /proc; a note elsewhere)."""
    task = Path(f"/proc/{pid}/task")
    rows = []
    try:
        tids = list(task.iterdir())
    except OSError as exc:
        return f"(no /proc threads: {exc})"
    ticks = os.sysconf("SC_CLK_TCK")
    for tid in tids:
        try:
            stat = (tid / "stat").read_text()
            wchan = (tid / "wchan").read_text().strip()
        except OSError:
            continue  # the thread ended meanwhile
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2 :].split()
        cpu = (int(fields[11]) + int(fields[12])) / ticks
        rows.append((cpu, f"  {tid.name:>8} {name:<16} {fields[0]} {cpu:8.1f} s  {wchan or '-'}"))
    rows.sort(reverse=True)
    lines = [r for _, r in rows[:limit]]
    if len(rows) > limit:
        lines.append(f"  ... {len(rows) - limit} more")
    return "\n".join(lines) or "(none)"


def native_stacks(pid: int, frames: int = 15) -> str:
    """The native stack of every thread of process ``pid`` (gdb attaches, prints, detaches;
    ./studio installs gdb for the tests)."""
    command = ["gdb", "-p", str(pid), "-batch", "-nx", "-ex", f"thread apply all bt {frames}"]
    try:
        r = subprocess.run(command, capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"(gdb failed: {exc})"
    lines = [line for line in r.stdout.splitlines() if line.startswith(("Thread ", "#", "("))]
    return "\n".join(lines) or f"(gdb printed no stack: {r.stderr.strip()[-500:]})"


def newest_files(folder: Path, limit: int = 5) -> str:
    """The newest files under ``folder`` with their age, newest first."""
    now = time.time()
    files = sorted((p for p in folder.rglob("*") if p.is_file()), key=lambda p: p.stat().st_mtime)
    lines = [f"  {p.relative_to(folder)}  ({now - p.stat().st_mtime:.0f} s ago)" for p in files]
    return "\n".join(reversed(lines[-limit:])) or "  (none)"
