"""The written word: a short README, guides whose commands run, a results page made by a command.

What a newcomer reads must not drift from the code: every ``dng`` command line in README.md and
docs/ parses, every relative link resolves, the README's results table is the generated page's
headline, and no machine path or experiment diary hides in the code's comments.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from app.cli import build_parser
from pipeline.report import SECTIONS, headline_markdown, headline_rows, results_markdown

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
#: The README's limits (bytes, lines) and the first screen, where the two commands must be.
README_MAX_BYTES = 30_000
README_MAX_LINES = 300
FIRST_SCREEN_LINES = 40
#: No comment block in the code is longer than this; the pipeline's config stays under its limit.
MAX_COMMENT_BLOCK = 12
CONFIG_MAX_LINES = 400
SCRATCH = "/" + "tmp/"  # spelled apart so this file does not name one
CODE_DIRS = ("app", "core", "pipeline", "training", "templates", "benchmarks", "tests")


def _pages() -> list[Path]:
    return [README, *sorted(DOCS.glob("*.md"))]


def _code_files() -> list[Path]:
    return [p for d in CODE_DIRS for p in sorted((ROOT / d).rglob("*.py"))]


def test_the_readme_is_short_and_opens_with_the_two_commands():
    text = README.read_text(encoding="utf-8")
    assert len(text.encode()) <= README_MAX_BYTES, f"README.md is {len(text.encode())} bytes"
    assert text.count("\n") <= README_MAX_LINES, f"README.md has {text.count(chr(10))} lines"
    first = "\n".join(text.splitlines()[:FIRST_SCREEN_LINES])
    assert "./studio demo" in first and "./studio test" in first


def test_no_page_or_code_comment_names_a_scratch_folder():
    hits = [
        f"{p.relative_to(ROOT)}:{i}"
        for p in [*_pages(), *_code_files()]
        for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
        if SCRATCH in line
    ]
    assert not hits, f"scratch folders named at {hits}"


def comment_blocks(text: str) -> list[tuple[int, int]]:
    """``(first line, length)`` of each run of consecutive ``#`` comment lines."""
    blocks, start, run = [], 0, 0
    for i, line in enumerate([*text.splitlines(), ""], 1):
        if line.strip().startswith("#"):
            start, run = (i, 1) if run == 0 else (start, run + 1)
        else:
            if run:
                blocks.append((start, run))
            run = 0
    return blocks


def test_comment_blocks_helper_counts_runs():
    assert comment_blocks("a\n# x\n# y\nb\n#z\n") == [(2, 2), (5, 1)]


def test_config_says_what_a_setting_is_not_its_history():
    long = [
        f"{p.relative_to(ROOT)}:{start} ({n} lines)"
        for p in _code_files()
        for start, n in comment_blocks(p.read_text(encoding="utf-8"))
        if n > MAX_COMMENT_BLOCK
    ]
    assert not long, f"comment blocks over {MAX_COMMENT_BLOCK} lines: {long}"
    lines = (ROOT / "pipeline" / "config.py").read_text(encoding="utf-8").count("\n")
    assert lines < CONFIG_MAX_LINES, f"pipeline/config.py has {lines} lines"


_FENCE = re.compile(r"^```.*?$(.*?)^```", re.S | re.M)
_SPAN = re.compile(r"(?<!`)`(dng [^`]+)`(?!`)")


def dng_lines(text: str) -> list[str]:
    """Every ``dng ...`` command in a page: lines of fenced blocks that start with ``dng`` (or
    ``.venv/bin/dng``, after an optional ``$ ``), and inline code spans that start with it."""
    found = []
    for block in _FENCE.findall(text):
        for line in block.splitlines():
            line = line.strip().removeprefix("$ ").removeprefix(".venv/bin/")
            if line.startswith("dng "):
                found.append(line.split("  #")[0].strip())
    prose = _FENCE.sub("", text)
    found += [m.replace("\\|", "|") for m in _SPAN.findall(prose)]
    return found


def test_dng_lines_finds_blocks_and_spans():
    text = "x `dng a b` y\n```sh\n$ .venv/bin/dng c --d  # note\nls\n```\n"
    assert dng_lines(text) == ["dng c --d", "dng a b"]


def _parses(parser, line: str) -> str | None:
    """None when ``line --help`` parses (argparse exits 0), else what argparse said."""
    try:
        argv = shlex.split(line)[1:]
    except ValueError as exc:
        return f"not a shell line: {exc}"
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            parser.parse_args([*argv, "--help"])
        except SystemExit as exc:
            return None if exc.code == 0 else err.getvalue().strip().splitlines()[-1]
    return "parsed without reaching --help"


def test_every_dng_line_in_the_readme_and_guides_parses():
    parser = build_parser()
    checked, bad = 0, []
    for page in _pages():
        for line in dng_lines(page.read_text(encoding="utf-8")):
            checked += 1
            problem = _parses(parser, line)
            if problem:
                bad.append(f"{page.relative_to(ROOT)}: `{line}`: {problem}")
    assert checked >= 20, f"only {checked} dng lines found: the extraction is broken"
    assert not bad, "\n".join(bad)


_LINK = re.compile(r"\]\(([^)\s]+)\)")


def test_every_relative_link_resolves():
    bad = []
    for page in _pages():
        for target in _LINK.findall(page.read_text(encoding="utf-8")):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            path, _, anchor = target.partition("#")
            resolved = (page.parent / path).resolve()
            if not resolved.exists():
                bad.append(f"{page.relative_to(ROOT)} -> {target}")
            elif anchor and resolved.suffix == ".md":
                anchors = {_anchor(h) for h in re.findall(r"^#+ (.+)$", resolved.read_text(), re.M)}
                if anchor not in anchors:
                    bad.append(f"{page.relative_to(ROOT)} -> {target} (no such section)")
    assert not bad, bad


def _anchor(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower().replace("`", ""))
    return text.replace(" ", "-")


def test_the_generated_page_has_every_section_the_readme_links_to(smoke_project):
    page = results_markdown(json.loads((smoke_project / "report.json").read_text()))
    headings = {_anchor(h) for h in re.findall(r"^## (.+)$", page, re.M)}
    assert {a for a, _ in SECTIONS} <= headings
    linked = re.findall(r"results\.md#([\w-]+)", README.read_text(encoding="utf-8"))
    assert linked and set(linked) <= headings


def _table_after(text: str, header: str) -> list[str]:
    lines = text.splitlines()
    start = lines.index(header)
    end = next((i for i in range(start, len(lines)) if not lines[i].startswith("|")), len(lines))
    return lines[start:end]


def test_the_readme_results_table_is_the_generated_headline():
    page = (DOCS / "results.md").read_text(encoding="utf-8")
    header = headline_markdown({})[0]
    table = _table_after(page, header)
    assert len(table) >= 5, "the results page has no headline table"
    assert _table_after(README.read_text(encoding="utf-8"), header) == table


def test_dng_report_writes_the_results_page_and_refuses_what_is_not_a_report(
    smoke_project, tmp_path
):
    out = tmp_path / "docs" / "results.md"
    readme = tmp_path / "README.md"
    readme.write_text(README.read_text(encoding="utf-8"), encoding="utf-8")
    dng = [sys.executable, "-m", "app.cli", "report"]
    done = subprocess.run(
        [*dng, str(smoke_project), "--results", str(out), "--readme", str(readme)],
        capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    page = out.read_text(encoding="utf-8")
    report = json.loads((smoke_project / "report.json").read_text())
    assert "\n".join(headline_markdown(report)) in page
    assert (report["provenance"]["commit"] or "Commit: not recorded") in page
    assert "embedded" in page
    assert (out.parent / "img" / "results-compare.png").is_file()
    header = headline_markdown({})[0]
    assert _table_after(readme.read_text(encoding="utf-8"), header) == headline_markdown(report)
    missing = subprocess.run(
        [*dng, str(tmp_path / "nowhere"), "--results", str(tmp_path / "r.md")],
        capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    assert missing.returncode == 2 and "report.json" in missing.stderr
    assert not (tmp_path / "r.md").exists()


@pytest.mark.parametrize("text", ["{", '{"no": "preset"}'])
def test_a_malformed_report_is_refused_by_name(tmp_path, dng, text):
    (tmp_path / "report.json").write_text(text)
    code, _, err = dng("report", str(tmp_path))
    assert code == 2 and "report.json" in err


def test_the_headline_says_when_a_run_reused_an_earlier_runs_stages():
    base = {"preset": "quick", "total_seconds": 150.0}
    fresh = {**base, "provenance": {"from_empty": True}}
    rerun = {**base, "provenance": {"from_empty": False}}
    assert headline_rows(fresh)[-1][1] == "2.5"
    assert headline_rows(rerun)[-1][1].startswith("2.5 (a rerun")
    assert "from an empty project folder" in results_markdown(fresh)
    assert "a rerun over an earlier run's stages" in results_markdown(rerun)
