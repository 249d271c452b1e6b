"""The toolkit's one cache folder, for every layer: ``$TRASE_BENCH_CACHE``, else
``~/.cache/trase-bench``. Synthetic scenes, scaled captures and model weights live in its
subfolders. A package below the others (masks and benchmark both read it), so that one
variable names the folder everywhere. ``$TRASE_CACHE``, an earlier name of the synthetic
scenes' folder, is still read where the new one is not set, with a notice."""

from __future__ import annotations

import os
import sys
from pathlib import Path

VARIABLE = "TRASE_BENCH_CACHE"
OLD_VARIABLE = "TRASE_CACHE"
_noticed: list[bool] = []


def root() -> Path:
    """The cache folder (not created here)."""
    value = os.environ.get(VARIABLE)
    if not value and os.environ.get(OLD_VARIABLE):
        value = os.environ[OLD_VARIABLE]
        if not _noticed:
            _noticed.append(True)
            print(f"trase-bench: ${OLD_VARIABLE} is read as ${VARIABLE} (the cache folder's one name); "
                  f"set ${VARIABLE} instead", file=sys.stderr)
    return Path(value).expanduser() if value else Path.home() / ".cache" / "trase-bench"


def subfolder(name: str) -> Path:
    """``root() / name``."""
    return root() / name


__all__ = ["OLD_VARIABLE", "VARIABLE", "root", "subfolder"]
