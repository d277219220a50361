"""One error type for bad input, so every stage and the CLI report it the same way."""

from __future__ import annotations

from os import PathLike


class InputError(ValueError):
    """Input that a stage refuses: names the file (when there is one) and the problem.

    The CLI prints ``str(error)`` on one line and exits with status 2.
    """

    def __init__(self, problem: str, path: str | PathLike | None = None):
        self.path = None if path is None else str(path)
        self.problem = problem
        super().__init__(problem if self.path is None else f"{self.path}: {problem}")
