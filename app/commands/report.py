"""``dng report PROJECT``: a project's report again from its ``report.json``, or the results page."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from core.errors import InputError
from core.fileio import atomic_open
from pipeline.demo import report_markdown
from pipeline.report import (
    headline_rows,
    load_report,
    results_markdown,
    with_headline,
    write_picture,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report",
        help="write a project's report.md again, or the results page (docs/results.md)",
        description=(
            "Read PROJECT/report.json (what `dng demo` measured). With no option, write "
            "PROJECT/report.md again and print the headline. With --results, write the results "
            "page: the headline, where the figures come from (preset, ground truth, commit, "
            "date, machine), Joint2Coarse, the renderers' V/U/P tables, simulation, speed, run "
            "time and the deviations from the paper, with the test motion's comparison picture "
            "copied beside it."
        ),
    )
    p.add_argument("project", help="a project folder made by `dng demo`")
    p.add_argument("--results", default=None, metavar="FILE.md", help="write the results page here")
    p.add_argument(
        "--readme", default=None, metavar="README.md",
        help="with --results: also update this page's copy of the headline table",
    )  # fmt: skip
    p.add_argument(
        "--bench", nargs="+", default=[], metavar="NAME=FILE.json",
        help="benchmark JSON to add to the results page (e.g. sim=OUT/sim/sim.json)",
    )  # fmt: skip
    p.set_defaults(handler=run)


def _benches(items: list[str]) -> dict[str, object]:
    out: dict[str, object] = {}
    for item in items:
        name, sep, file = item.partition("=")
        if not sep or not name or not file:
            raise InputError(f"--bench expects NAME=FILE.json, got {item!r}")
        path = Path(file)
        try:
            out[name] = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise InputError(f"{path}: no such benchmark file") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{path}: not readable JSON: {exc}") from None
    return out


def run(args: argparse.Namespace) -> int:
    report = load_report(args.project)
    benches = _benches(args.bench)
    if args.results is None:
        if benches or args.readme:
            raise InputError("--bench and --readme go with --results")
        out = Path(args.project) / "report.md"
        with atomic_open(out, "w", encoding="utf-8") as f:
            f.write(report_markdown(report))
        print(f"wrote {out}")
        for what, figure in headline_rows(report):
            print(f"  {what}: {figure}")
        return 0
    out = Path(args.results)
    if out.suffix.lower() != ".md":
        raise InputError(f"{out}: the results page is Markdown (.md)")
    readme = None
    if args.readme is not None:
        path = Path(args.readme)
        if not path.is_file():
            raise InputError(f"{path}: no such file")
        readme = with_headline(path.read_text(encoding="utf-8"), report, path)
    picture = write_picture(Path(args.project), out.parent, report)
    with atomic_open(out, "w", encoding="utf-8") as f:
        f.write(results_markdown(report, benches, picture=picture))
    print(f"wrote {out}" + (f" and {out.parent / picture}" if picture else ""))
    if readme is not None:
        with atomic_open(args.readme, "w", encoding="utf-8") as f:
            f.write(readme)
        print(f"updated the results table in {args.readme}")
    return 0
