"""How many threads numba's parallel kernels and torch get, shared by every module that trains."""

from __future__ import annotations

import contextlib

import numba
import torch


@contextlib.contextmanager
def numba_threads(work: int = 0, min_work: int = 0):
    """Run numba's parallel kernels on as many threads as torch uses (at most numba's pool),
    or on one (callers then run their serial driver; numba's pool untouched) when
    ``work < min_work``: waking the pool costs more than small work saves. Yields the count.

    Numba's OpenMP layer shares the OpenMP runtime with torch, so setting numba's count also
    changes ``torch.get_num_threads()`` (measured): torch's count is restored on exit."""
    torch_n = torch.get_num_threads()
    n = max(1, min(torch_n, numba.config.NUMBA_NUM_THREADS))
    if n == 1 or work < min_work:
        yield 1
        return
    old = numba.get_num_threads()
    numba.set_num_threads(n)
    try:
        yield n
    finally:
        numba.set_num_threads(old)
        torch.set_num_threads(torch_n)


@contextlib.contextmanager
def torch_threads(n: int | None):
    """torch's intra-op threads set to ``n`` inside the block (``None`` or < 1: as they are),
    restored on exit: a stage's thread count is part of its config, not the process's.

    Numba's thread pool is started first: its start sets the OpenMP thread count that torch
    (and MKL) read to numba's, and where the block's first parallel kernel started it, the
    stage ran on numba's count instead of ``n``, but only in a process where no numba kernel
    had run before (a stage after a cached one), with other bits."""
    numba.get_num_threads()  # starts the pool (once per process)
    old = torch.get_num_threads()
    if n is not None and int(n) > 0:
        torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(old)
