"""Dataset files: JSON (benchmark.io's reader, raising DatasetError) and numeric fields, with
errors that name the file and the field."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from benchmark.datasets.errors import DatasetError, fail
from benchmark.io import read_json as _read_json


def read_json(path: Path | str, what: str = "file") -> Any:
    """benchmark.io's reader, raising DatasetError."""
    return _read_json(path, what, DatasetError)


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
