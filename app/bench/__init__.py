"""Benchmarks behind ``dng bench``: one module per bench, each with ``add_arguments(parser)``,
``run(args)`` and optionally ``HELP``. Modules not written yet are skipped."""

from __future__ import annotations

from pathlib import Path

from core.errors import InputError

#: Known benches, in the order ``dng bench --help`` lists them.
BENCHES = ("proxy", "sim", "raster", "render", "train", "trade", "placement", "all")
#: Benches that measure a trained project (``--project DIR``, required).
PROJECT_BENCHES = ("trade", "placement")
#: Where benches write their JSON tables and PNG plots unless told otherwise.
DEFAULT_OUT = "out/bench"


def add_output_arguments(parser) -> None:
    """The usual ``--out DIR`` (default ``out/bench``) and ``--json`` flags."""
    parser.add_argument(
        "--out", default=DEFAULT_OUT, metavar="DIR",
        help=f"folder for the JSON table and PNG plot (default: {DEFAULT_OUT})",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print the table as JSON on stdout")


def project_test_sets(root, config) -> list[str]:
    """The project's test motions that have a test set (``testset/NAME/samples.json``): those of
    ``config.test_motions`` first, in its order, then any others by name; never the training
    motion (its test set, from unseen cameras, is the evaluation's protocol P, not an unseen
    motion) nor the renderers' validation motion (protocol V: where settings are chosen, not
    a test). InputError when there is none."""
    root = Path(root)
    not_tests = {config.train_motion.name, config.renderer_validation}
    have = sorted(
        p.parent.name
        for p in (root / "testset").glob("*/samples.json")
        if p.parent.name not in not_tests
    )
    if not have:
        raise InputError("no test set: run dng demo (the testset stage) first", root / "testset")
    order = [m.name for m in config.test_motions if m.name in have]
    return order + [n for n in have if n not in order]
