"""Crash-safe file output: every file and directory appears whole or not at all.

Writes go to a temporary sibling named ``.<name>.<random>.tmp`` and are moved into place with
``os.replace`` (atomic on POSIX within one file system). A process killed mid-write leaves
only such a temporary; the next write of the same path sweeps it away, so a resumed run ends
with no stray files. (Two processes writing the same path at once is not supported.)
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


def _sweep(path: Path) -> None:
    """Remove temporaries of ``path`` left by a writer that was killed."""
    for stale in path.parent.glob(f".{path.name}.*.tmp"):
        if stale.is_dir():
            shutil.rmtree(stale, ignore_errors=True)
        else:
            stale.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[str]:
    """Yield a temporary file path to write; it becomes ``path`` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _sweep(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def atomic_torch_save(obj, path: str | Path) -> None:
    """``torch.save`` made atomic. Saved through memory, so the archive inside is named the same
    whatever the temporary file's name: the same object gives the same bytes."""
    import io

    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    atomic_write_bytes(path, buf.getvalue())


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


@contextlib.contextmanager
def atomic_directory(final: str | Path) -> Iterator[Path]:
    """Yield a fresh temporary directory that replaces ``final`` only if the block succeeds."""
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    _sweep(final)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent))
    try:
        yield tmp
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def read_torch(path: str | Path, error: type[Exception], unreadable: str = "not a readable torch state dict"):
    """``torch.load`` of a local file (CPU, weights only); a damaged file raises ``error`` with
    one line: "<path>: <unreadable> (ExcType: first line)". Callers check that it exists."""
    import torch

    from masks.store import first_line  # torch's real cause, not its long weights_only notice

    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many types for a damaged file
        raise error(f"{path}: {unreadable} ({first_line(exc)})") from None
