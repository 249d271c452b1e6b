"""The one error class every dataset loader raises for bad input.

Its message names the file (or directory) and the problem on one line; the CLI prints it as
``error: <message>`` and exits 1 (see ``benchmark.errors``).
"""

from __future__ import annotations

from pathlib import Path

from benchmark.errors import UserError


class DatasetError(UserError):
    """Bad or missing dataset input: a file, its path and what is wrong with it."""

    user_facing = True


def fail(path: Path | str, problem: str) -> DatasetError:
    """``raise fail(path, "...")``: one line, the file first."""
    return DatasetError(f"{path}: {problem}")
