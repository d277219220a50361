"""``dng bench NAME``: benchmarks, one module per bench under :mod:`app.bench`.

Each bench module defines ``add_arguments(parser)`` and ``run(args) -> int`` and may define
``HELP`` (one line; the module docstring's first line otherwise). A bench listed in
:data:`app.bench.BENCHES` whose module is not there yet is skipped.
"""

from __future__ import annotations

import argparse

from app.bench import BENCHES
from app.commands import present_modules


def register(subparsers) -> None:

    p = subparsers.add_parser(
        "bench",
        help="measure speed/quality trade-offs (JSON tables, PNG plots)",
        description="Benchmarks: each prints a table and writes its results as JSON.",
    )
    sub = p.add_subparsers(dest="bench", metavar="BENCH")
    sub.required = True
    for name, module in present_modules("app.bench", BENCHES):
        text = getattr(module, "HELP", None) or (module.__doc__ or name).strip().splitlines()[0]
        b = sub.add_parser(name, help=text, description=module.__doc__)
        module.add_arguments(b)
        b.set_defaults(handler=_runner(module))


def _runner(module):
    def run(args: argparse.Namespace) -> int:
        return int(module.run(args) or 0)

    return run
