"""File I/O for the benchmark: atomic writes (from ``trase.io``), JSON with one-line errors,
checksums. A run killed at any moment leaves the old file or the new one, never half of one.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from trase.io import atomic_directory, atomic_write_bytes, atomic_write_text  # noqa: F401 (re-exported)


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


def read_json(path: str | Path, what: str = "JSON file"):
    """Read JSON with a one-line error naming the file (missing, not UTF-8, malformed)."""
    from benchmark.errors import UserError

    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise UserError(f"{path}: {what} not found") from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read {what} ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UserError(f"{path}: {what} is not UTF-8 (byte {exc.start})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise UserError(f"{path}: malformed {what} (line {exc.lineno}: {exc.msg})") from None
