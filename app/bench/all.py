"""``dng bench all``: every other bench with its default settings, one subfolder each.

Runs ``proxy``, ``sim``, ``raster``, ``render`` and, with ``--project``, ``trade`` and
``placement`` (which need a trained project) one after another, each into ``OUT/NAME/`` with
the arguments its own ``add_arguments`` gives by default, and writes ``OUT/all.json``: for each
bench whether it ran, its exit code (2 for bad input, 1 for a crash, whose message is kept), its
wall seconds and the machine's load average before it. A failing bench does not stop the others.
With the defaults this takes a long time (the simulation bench alone runs garments of 10k and 30k
vertices); ``--only NAME ...`` picks some.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from pathlib import Path

from app.bench import BENCHES, PROJECT_BENCHES, add_output_arguments
from app.commands import present_modules
from core.errors import InputError
from core.fileio import write_json

HELP = "run every bench with its defaults into subfolders, and a summary JSON"


def add_arguments(parser: argparse.ArgumentParser) -> None:

    add_output_arguments(parser)
    parser.add_argument(
        "--project",
        default=None,
        help="a trained project: also runs the trade and placement benches on it",
    )
    parser.add_argument(
        "--only", nargs="+", default=None, metavar="NAME", help="run only these benches"
    )


def bench_names() -> list[str]:
    """Every bench but this one, in :data:`app.bench.BENCHES` order."""
    return [name for name in BENCHES if name != "all"]


def load_benches(names: list[str]) -> dict:
    """name -> bench module, for the modules that exist."""
    return dict(present_modules("app.bench", names))


def default_args(module, argv: list[str]) -> argparse.Namespace:
    """The module's arguments as its own parser gives them for ``argv`` (defaults otherwise)."""
    parser = argparse.ArgumentParser(prog=f"dng bench {module.__name__.rsplit('.', 1)[-1]}")
    module.add_arguments(parser)
    return parser.parse_args(argv)


def run(args: argparse.Namespace) -> int:

    names = bench_names()
    if args.only:
        unknown = sorted(set(args.only) - set(names))
        if unknown:
            raise InputError(f"unknown bench(es) {unknown}; choose from {', '.join(names)}")
        names = [n for n in names if n in args.only]
    modules = load_benches(names)
    out = Path(args.out)
    say = (lambda *a: None) if args.json else (lambda *a: print(*a, flush=True))
    results = []
    for name in names:
        record = {"bench": name, "ran": False, "exit_code": None, "seconds": None}
        results.append(record)
        if name not in modules:
            record["skipped"] = "module not written yet"
            continue
        argv = ["--out", str(out / name)]
        if name in PROJECT_BENCHES:
            if not args.project:
                record["skipped"] = "needs --project"
                say(f"== {name}: skipped (needs --project)")
                continue
            argv += ["--project", str(args.project)]
        record["load_average_before"] = list(os.getloadavg())
        say(f"== {name}: dng bench {name} {' '.join(argv)}")
        start = time.perf_counter()
        # With --json, stdout carries only the summary: the benches' own tables go to stderr.
        quiet = contextlib.redirect_stdout(sys.stderr) if args.json else contextlib.nullcontext()
        try:
            with quiet:
                code = int(modules[name].run(default_args(modules[name], argv)) or 0)
        except InputError as exc:
            code, record["error"] = 2, str(exc)
        except Exception as exc:  # noqa: BLE001 - one bench's crash must not stop the others
            code, record["error"] = 1, f"{type(exc).__name__}: {exc}"
        except SystemExit as exc:  # an argparse error inside a bench's own parser
            code, record["error"] = int(exc.code or 0), "argument error"
        record.update(ran=True, exit_code=code, seconds=time.perf_counter() - start)
        if "error" in record:
            print(f"dng bench {name}: error: {record['error']}", file=sys.stderr)
        say(f"== {name}: exit {code} in {record['seconds']:.1f} s")
    summary = {
        "bench": "all",
        "out": str(out),
        "project": args.project,
        "cpus": os.cpu_count(),
        "load_average_after": list(os.getloadavg()),
        "benches": results,
    }
    write_json(out / "all.json", summary)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        for r in results:
            state = (
                f"exit {r['exit_code']} in {r['seconds']:.1f} s"
                if r["ran"]
                else f"skipped ({r.get('skipped')})"
            )
            print(f"{r['bench']:>8}: {state}")
        print(f"wrote {out / 'all.json'}")
    failed = [r for r in results if r["ran"] and r["exit_code"]]
    return 1 if failed else 0
