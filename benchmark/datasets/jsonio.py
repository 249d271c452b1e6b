"""Reading JSON and numeric fields with errors that name the file and the field."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from benchmark.datasets.errors import fail


def read_json(path: Path | str, what: str = "file") -> Any:
    path = Path(path)
    if not path.is_file():
        raise fail(path, f"missing {what}")
    try:
        with path.open("r", encoding="utf-8") as f:
            return json.load(f)
    except json.JSONDecodeError as exc:
        raise fail(path, f"malformed JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise fail(path, f"cannot read {what} ({exc.__class__.__name__})") from None


def field(d: Any, key: str, path: Path | str, where: str = "") -> Any:
    """``d[key]`` or an error naming the file and the missing key."""
    if not isinstance(d, dict):
        raise fail(path, f"{where or 'top level'} is not a JSON object")
    if key not in d:
        raise fail(path, f"missing key {key!r}" + (f" in {where}" if where else ""))
    return d[key]


def finite_array(value: Any, path: Path | str, name: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """A float64 array with the given shape and only finite values."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise fail(path, f"{name} is not numeric") from None
    if shape is not None and arr.shape != shape:
        raise fail(path, f"{name} has shape {arr.shape}, expected {shape}")
    if not np.isfinite(arr).all():
        raise fail(path, f"{name} contains NaN or Inf")
    return arr


def finite_float(value: Any, path: Path | str, name: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise fail(path, f"{name} is not a number: {value!r}") from None
    if not math.isfinite(x):
        raise fail(path, f"{name} is NaN or Inf")
    return x
