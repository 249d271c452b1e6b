"""File I/O for the benchmark: atomic writes (from ``trase.io``), JSON with one-line errors,
checksums. A run killed at any moment leaves the old file or the new one, never half of one.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from trase.io import atomic_directory, atomic_path, atomic_write_bytes, atomic_write_text  # noqa: F401 (re-exported)


def atomic_write_json(path: str | Path, obj) -> None:
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=False, allow_nan=False) + "\n")


def sha256_files(paths: list[Path]) -> str:
    """One digest over the names and bytes of ``paths`` (order given by the caller)."""
    h = hashlib.sha256()
    for p in paths:
        p = Path(p)
        h.update(p.name.encode())
        h.update(b"\0")
        h.update(hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()


def read_json(path: str | Path, what: str = "JSON file", error: type[Exception] | None = None):
    """Read JSON with a one-line error naming the file: "<path>: <what> not found", "cannot
    read <what> (reason)", "<what> is not UTF-8 (byte N)", "malformed JSON in <what> (line L,
    column C: reason)"; <what> is "file" when it would only repeat the file's name. ``error``:
    the exception class to raise (UserError by default; dataset loaders pass DatasetError)."""
    from benchmark.errors import UserError

    error = error or UserError
    path = Path(path)
    what = "file" if what in ("", path.name) else what
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise error(f"{path}: {what} not found") from None
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror or exc.__class__.__name__})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: {what} is not UTF-8 (byte {exc.start})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        where = "" if what == "file" else f" in {what}"
        raise error(f"{path}: malformed JSON{where} (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None