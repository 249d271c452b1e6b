"""Numba loops that cut a matrix product into fixed row chunks, one OpenBLAS call each
(``trase.blas_linear``'s ``openblas`` engine); ``reference_*`` are the plain products they are
tested against.

A chunk's product is one single-threaded ``sgemm``/``dgemm`` (numba's ``np.dot`` calls the
OpenBLAS scipy ships). Its rounding depends on the chunk's rows alone, never on which thread
runs it, so the bits are the same on any thread count; a sum over rows (a weight's gradient)
adds the chunks' partial products one after another in chunk order.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit, prange

CHUNK = 1024  # rows per OpenBLAS call: part of the bits (a product's rounding follows its tiling)


def n_chunks(rows: int) -> int:
    return (rows + CHUNK - 1) // CHUNK


@functools.cache
def _openblas_libraries() -> tuple:
    """threadpoolctl's controllers of the OpenBLAS libraries loaded (numpy's and scipy's)."""
    import scipy.linalg.cython_blas  # noqa: F401  (numba's np.dot calls the OpenBLAS it loads)
    from threadpoolctl import ThreadpoolController

    return tuple(ThreadpoolController().select(internal_api="openblas").lib_controllers)


def single_threaded_blas() -> None:
    """OpenBLAS's own threads off (a microsecond when they already are): its calls come from
    numba's threads, and OpenBLAS's threaded build must not be entered from inside an OpenMP
    loop (it warns that it may hang). Checked on every product, since a ``threadpool_limits``
    block elsewhere restores the count it found when it ends."""
    for library in _openblas_libraries():
        if library.get_num_threads() != 1:
            library.set_num_threads(1)


@njit(cache=True, nogil=True)
def rows_chunk(a, b, out, c):
    """out[chunk c] = a[chunk c] @ b for a [N, K], b [K, M], out [N, M] (C-contiguous)."""
    i0 = c * CHUNK
    i1 = min(a.shape[0], i0 + CHUNK)
    np.dot(a[i0:i1], b, out[i0:i1])


@njit(cache=True, nogil=True)
def transposed_chunk(g, x, partial, c):
    """partial[c] [O, I] = g[chunk c].T @ x[chunk c] for g [N, O], x [N, I] (C-contiguous). The
    transposed chunk goes to OpenBLAS as it lies (Fortran order, a transpose flag), without a
    copy. With the Haswell kernels portable numerics pin, the network's shapes get the same bits
    as from a C-ordered copy; other kernels (SkylakeX) round some other shapes differently."""
    i0 = c * CHUNK
    i1 = min(g.shape[0], i0 + CHUNK)
    np.dot(g[i0:i1].T, x[i0:i1], partial[c])


@njit(parallel=True, cache=True, nogil=True)
def rows_times(a, b, out):
    """``rows_chunk`` for every chunk, over numba's threads."""
    for c in prange((a.shape[0] + CHUNK - 1) // CHUNK):
        rows_chunk(a, b, out, c)


@njit(parallel=True, cache=True, nogil=True)
def transposed_times(g, x, partial):
    """``transposed_chunk`` for every chunk, over numba's threads."""
    for c in prange((g.shape[0] + CHUNK - 1) // CHUNK):
        transposed_chunk(g, x, partial, c)


@njit(cache=True, nogil=True)
def relu_sum_chunk(a, b, a2, b2, two, row, out, c):
    """out[chunk c] = relu((a @ b [+ a2 @ b2 where ``two``]) + row), the sums in that order, for
    a [N, K], b [K, M], a2 [N, K2], b2 [K2, M], row [M], out [N, M] (C-contiguous). The ReLU is
    torch's (NaN kept, -0 kept: ``0 if v < 0 else v``)."""
    i0 = c * CHUNK
    i1 = min(a.shape[0], i0 + CHUNK)
    np.dot(a[i0:i1], b, out[i0:i1])
    second = np.empty((i1 - i0 if two else 0, out.shape[1]), dtype=out.dtype)
    if two:
        np.dot(a2[i0:i1], b2, second)
    for i in range(i0, i1):
        for j in range(out.shape[1]):
            v = out[i, j]
            if two:
                v = v + second[i - i0, j]
            v = v + row[j]
            out[i, j] = 0.0 if v < 0 else v


@njit(cache=True, nogil=True)
def relu_grad_chunk(grad, y, out, c):
    """out[chunk c] = the gradient through a ReLU whose output is ``y``: 0 where y <= 0, else
    ``grad`` (torch's ``threshold_backward``), [N, M] each."""
    i0 = c * CHUNK
    i1 = min(grad.shape[0], i0 + CHUNK)
    for i in range(i0, i1):
        for j in range(grad.shape[1]):
            out[i, j] = 0.0 if y[i, j] <= 0 else grad[i, j]


@njit(parallel=True, cache=True, nogil=True)
def relu_sum_times(a, b, a2, b2, two, row, out):
    """``relu_sum_chunk`` for every chunk, over numba's threads."""
    for c in prange((a.shape[0] + CHUNK - 1) // CHUNK):
        relu_sum_chunk(a, b, a2, b2, two, row, out, c)


@njit(parallel=True, cache=True, nogil=True)
def relu_grad_times(grad, y, out):
    """``relu_grad_chunk`` for every chunk, over numba's threads."""
    for c in prange((grad.shape[0] + CHUNK - 1) // CHUNK):
        relu_grad_chunk(grad, y, out, c)


def on_this_thread(chunk_kernel, rows: int, *arrays) -> None:
    """A chunk kernel for every chunk in order, on the calling thread: one thread does not wake
    numba's pool (a few calls from Python, against the pool's wake-up on a loaded machine)."""
    for c in range(n_chunks(rows)):
        chunk_kernel(*arrays, c)


def sum_in_order(partial: np.ndarray) -> np.ndarray:
    """[C, O, I] -> [O, I]: the chunks' partial products added in chunk order (zeros if none)."""
    if partial.shape[0] == 0:
        return np.zeros(partial.shape[1:], dtype=partial.dtype)
    total = partial[0].copy()
    for p in partial[1:]:
        total += p
    return total


def reference_rows_times(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The plain product in float64: what ``rows_times`` computes up to float32 rounding."""
    return a.astype(np.float64) @ b.astype(np.float64)


def reference_relu_sum(a: np.ndarray, b: np.ndarray, row: np.ndarray, a2: np.ndarray | None = None,
                       b2: np.ndarray | None = None) -> np.ndarray:
    """The plain relu(a b [+ a2 b2] + row) in float64."""
    total = reference_rows_times(a, b) + (0.0 if a2 is None else reference_rows_times(a2, b2))
    return np.maximum(total + row.astype(np.float64), 0.0)


def reference_transposed_times(g: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The plain g^T x in float64."""
    return g.astype(np.float64).T @ x.astype(np.float64)
