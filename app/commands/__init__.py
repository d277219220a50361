"""One module per ``dng`` subcommand. Each defines ``register(subparsers)``.

Command modules import only argparse-level things at import time; the work (and heavy
libraries) is imported inside the handler, so ``dng --help`` stays fast.
"""

import importlib

#: Subcommand modules in the order ``dng --help`` lists them. A module that is not there yet
#: (a later issue's) is skipped.
COMMANDS = (
    "demo", "motion", "body", "garment", "proxy", "simulate", "dataset",
    "train", "predict", "render", "finetune", "eval", "bench", "export", "gui",
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
