"""One module per ``dng`` subcommand. Each defines ``register(subparsers)``.

Command modules import only argparse-level things at import time; the work (and heavy
libraries) is imported inside the handler, so ``dng --help`` stays fast.
"""

import importlib
import json

from core.errors import InputError

#: Subcommand modules in the order ``dng --help`` lists them. A module that is not there yet
#: (a later issue's) is skipped.
COMMANDS = (
    "demo", "motion", "body", "garment", "proxy", "simulate", "dataset",
    "train", "predict", "render", "finetune", "eval", "report", "bench", "export", "gui",
)  # fmt: skip


def present_modules(package: str, names):
    """Import ``package.name`` for each name, skipping the modules not written yet.

    Yields ``(name, module)``. An import error inside a module that exists is raised, not hidden.
    """
    for name in names:
        try:
            module = importlib.import_module(f"{package}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"{package}.{name}":
                continue
            raise
        yield name, module


def parse_setting(item: str) -> tuple[str, object]:
    """``"KEY=VALUE"`` -> (key, value), the value read as JSON when it parses, else a string.

    >>> parse_setting("w_gan=0.1")
    ('w_gan', 0.1)
    """
    key, sep, text = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise InputError(f"--set expects KEY=VALUE, got {item!r}")
    try:
        return key, json.loads(text)
    except json.JSONDecodeError:
        return key, text
