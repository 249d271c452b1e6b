"""The numba kernels' 16-lane vector helpers (LLVM IR intrinsics) against plain numpy, for
channel counts around the chunk sizes (16 for vectors, 4 for accumulators) and empty lists."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from trase.render.numba_kernels import LANES, lanes_dot_rows, lanes_times_rows, rows_dot_lanes


@njit(cache=False)
def _times(acc, wl, ids, n, rows):
    lanes_times_rows(acc, wl, ids, n, rows)


@njit(cache=False)
def _dot(out, ids, n, rows, gt):
    rows_dot_lanes(out, ids, n, rows, gt)


@njit(cache=False)
def _back(buf, eids, n, wl, gl):
    lanes_dot_rows(buf, eids, n, wl, gl)


def _data(c, n, seed):
    rng = np.random.default_rng(seed)
    rows = rng.standard_normal((50, c)).astype(np.float32)
    ids = rng.integers(0, 50, size=n + 3).astype(np.int64)  # longer than n: only n are read
    wl = rng.random((n + 3, LANES)).astype(np.float32)
    return rng, rows, ids, wl


@pytest.mark.parametrize("c", [1, 3, 4, 5, 15, 16, 17, 36, 40])
@pytest.mark.parametrize("n", [0, 1, 7])
def test_lanes_times_rows(c, n):
    rng, rows, ids, wl = _data(c, n, c * 10 + n)
    acc = rng.standard_normal((c, LANES)).astype(np.float32)
    want = acc.astype(np.float64) + (rows[ids[:n]].astype(np.float64).T @ wl[:n].astype(np.float64))
    _times(acc, wl, ids, n, rows)
    assert np.allclose(acc, want, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("c", [1, 3, 4, 5, 16, 17, 36])
@pytest.mark.parametrize("n", [0, 1, 7])
def test_rows_dot_lanes(c, n):
    rng, rows, ids, _ = _data(c, n, c * 10 + n + 1)
    gt = rng.standard_normal((c, LANES)).astype(np.float32)
    out = np.full((n + 3, LANES), 7.0, np.float32)
    _dot(out, ids, n, rows, gt)
    want = rows[ids[:n]].astype(np.float64) @ gt.astype(np.float64)
    assert np.allclose(out[:n], want, atol=1e-5, rtol=1e-5)
    assert np.all(out[n:] == 7.0)  # rows past n untouched


@pytest.mark.parametrize("cp", [16, 32, 48])
@pytest.mark.parametrize("n", [0, 1, 7])
def test_lanes_dot_rows(cp, n):
    """Channels padded to a multiple of 16 (the helper's contract); gl wider than buf is fine."""
    rng, _, _, wl = _data(cp, n, cp * 10 + n + 2)
    eids = rng.permutation(20)[: n + 3].astype(np.int64)  # distinct rows, as in the backward
    gl = rng.standard_normal((LANES, cp + 16)).astype(np.float32)
    buf = rng.standard_normal((20, cp)).astype(np.float32)
    want = buf.astype(np.float64).copy()
    want[eids[:n]] += wl[:n].astype(np.float64) @ gl[:, :cp].astype(np.float64)
    _back(buf, eids, n, wl, gl)
    assert np.allclose(buf, want, atol=1e-5, rtol=1e-5)
