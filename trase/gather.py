"""Numba gather / scatter kernels for the two sparse linear maps of a feature-training step:
KNN smoothing (a mean over k neighbour slots of L2-normalised features) and the fast path's
render (a weighted sum over a pixel's CSR row of contributing gaussians).

Why: torch's CPU ``embedding_bag`` forward is fast, but its backward (a sort of the bag indices
then a segmented reduction) costs ~15 ms for 24k gaussians x 8 slots x 32 dims, and
``F.normalize`` adds ~4 ms of small autograd ops; the same maps written as direct loops cost
~1-2 ms forward + backward. The reference implementations (``embedding_bag``) stay in
trase.smoothing / trase.fastpath and the tests compare against them.

Backward scatters (grad[idx] += w * g) are split by COLUMN blocks across threads, never by
rows: no two threads write the same element, no atomics, and every element is summed in the
same order whatever the thread count (results are bit-identical at 1 and 2 threads).
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange

from trase.threads import numba_threads

COLUMN_BLOCK = 8  # at least this many columns per thread in a scatter (one AVX register of float32)
PARALLEL_MIN_WORK = 1 << 16  # rows * cols below which one thread runs (waking numba's pool costs more)


class GatherImplError(ValueError):
    user_facing = True


def use_fused(t: torch.Tensor, impl: str, what: str) -> bool:
    """impl 'auto' -> fused kernels for CPU float32/float64 tensors, reference otherwise;
    'fused' on anything else is an error; 'reference' -> the torch reference."""
    ok = t.device.type == "cpu" and t.dtype in (torch.float32, torch.float64)
    if impl == "auto":
        return ok
    if impl == "fused":
        if not ok:
            raise GatherImplError(f"{what}: impl='fused' needs CPU float32/float64 features, got {t.dtype} on {t.device}")
        return True
    if impl == "reference":
        return False
    raise GatherImplError(f"{what}: unknown impl {impl!r} (expected 'auto', 'fused' or 'reference')")


def column_split(D: int, threads: int) -> int:
    """Number of equal column blocks for a scatter: the largest nb <= threads dividing D with
    blocks of >= COLUMN_BLOCK columns (1 if none). Kernels see [rows, nb, D // nb] views:
    with constant-start inner loops LLVM vectorises them (column ranges [c0, c1) read from an
    array measured ~5x slower)."""
    for nb in range(max(1, min(threads, D // COLUMN_BLOCK)), 1, -1):
        if D % nb == 0:
            return nb
    return 1


def _one(t: torch.Tensor):
    """1 as a numpy scalar of t's dtype (numba types it as that dtype, not float64)."""
    return np.ones(1, dtype=t.numpy().dtype)[0]


def _twice(fn):
    """(serial, parallel) compilations of one kernel (prange is range in the serial one)."""
    return njit(cache=True, nogil=True)(fn), njit(parallel=True, cache=True, nogil=True)(fn)


# ---------------------------------------------------------------------------------------------
# smoothing: y[i] = (1 / k) sum_s fhat[slots[i, s]],  fhat = f / max(|f|, eps)

def _normalise_rows(f, eps, one, fhat, denom):
    """f [N, D] -> fhat [N, D] = f / max(|f|, eps) (as F.normalize), denom [N] = max(|f|, eps);
    denom is negated where |f| < eps (the clamp is active: no gradient through the norm).
    The norm is summed in float64; the per-element work stays in the arrays' dtype."""
    N, D = f.shape
    for i in prange(N):
        s = 0.0
        for c in range(D):
            s += f[i, c] * f[i, c]
        n = np.sqrt(s)
        denom[i] = max(n, eps)
        inv = one / denom[i]  # ``one`` is a scalar of f's dtype: float32 stays float32
        # (one division per row; f * inv is within 1 ulp of F.normalize's f / d)
        for c in range(D):
            fhat[i, c] = f[i, c] * inv
        if n < eps:
            denom[i] = -denom[i]


def _bag_mean(fhat, slots, out):
    """out [N, D] = mean over the k slots of fhat[slots[i, s]] (slots [N, k])."""
    N, k = slots.shape
    D = fhat.shape[1]
    scale = 1.0 / k
    for i in prange(N):
        for c in range(D):
            out[i, c] = 0.0
        for s in range(k):
            j = slots[i, s]
            for c in range(D):
                out[i, c] += fhat[j, c]
        for c in range(D):
            out[i, c] *= scale


def _bag_mean_backward(gy, slots, gfhat):
    """gfhat [N, nb, Db] (zeroed) += gy[i] at every slots[i, s]; gy [N, nb, Db]: one thread per
    column block. The caller scales gy by 1 / k first (a float64 scale here would stop float32
    vectorisation)."""
    N, k = slots.shape
    nb, Db = gy.shape[1], gy.shape[2]
    for b in prange(nb):
        for i in range(N):
            for s in range(k):
                j = slots[i, s]
                for c in range(Db):
                    gfhat[j, b, c] += gy[i, b, c]


def _normalise_backward(fhat, denom, one, g):
    """In place: g [N, D] (gradient w.r.t. fhat) -> gradient w.r.t. f, as autograd of
    f / clamp_min(|f|, eps): (g - fhat (fhat . g)) / |f|, or g / eps where the clamp is active."""
    N, D = fhat.shape
    for i in prange(N):
        d = denom[i]
        if d > 0:
            dot = d * 0  # in the arrays' dtype
            for c in range(D):
                dot += fhat[i, c] * g[i, c]
            inv = one / d
            for c in range(D):
                g[i, c] = (g[i, c] - fhat[i, c] * dot) * inv
        else:
            inv = -one / d
            for c in range(D):
                g[i, c] = g[i, c] * inv


NORMALISE = _twice(_normalise_rows)
BAG_MEAN = _twice(_bag_mean)
BAG_MEAN_BACKWARD = _twice(_bag_mean_backward)
NORMALISE_BACKWARD = _twice(_normalise_backward)


class SmoothMean(torch.autograd.Function):
    """features [N, D], slots [N, k] int64 -> [N, D] mean of the L2-normalised features at the
    k slots of each row. Forward and backward are the numba kernels above (CPU float32/64)."""

    @staticmethod
    def forward(ctx, features: torch.Tensor, slots: torch.Tensor, eps: float) -> torch.Tensor:
        f = features.detach().contiguous()
        sl = slots.contiguous().numpy()
        N, D = f.shape
        fhat = torch.empty_like(f)
        denom = torch.empty(N, dtype=f.dtype)
        out = torch.empty_like(f)
        with numba_threads(N * D, PARALLEL_MIN_WORK) as nt:
            par = int(nt > 1)
            NORMALISE[par](f.numpy(), eps, _one(f), fhat.numpy(), denom.numpy())
            BAG_MEAN[par](fhat.numpy(), sl, out.numpy())
        ctx.save_for_backward(fhat, denom, slots)
        return out

    @staticmethod
    def backward(ctx, gy: torch.Tensor):
        fhat, denom, slots = ctx.saved_tensors
        k = slots.shape[1]
        g = (gy.detach().to(fhat.dtype) * (1.0 / k)).contiguous()  # [N, D] mean's 1 / k first
        N, D = fhat.shape
        grad = torch.zeros_like(fhat)
        with numba_threads(N * D, PARALLEL_MIN_WORK) as nt:
            par = int(nt > 1)
            nb = column_split(D, nt)
            BAG_MEAN_BACKWARD[par](g.numpy().reshape(N, nb, D // nb), slots.contiguous().numpy(),
                                   grad.numpy().reshape(N, nb, D // nb))
            NORMALISE_BACKWARD[par](fhat.numpy(), denom.numpy(), _one(fhat), grad.numpy())
        return grad, None, None


# ---------------------------------------------------------------------------------------------
# fast-path render: out[p] = sum_{q in row r_p} w_q f[g_q]  (CSR indptr / indices / weights)

def _csr_rows(rows, indptr, indices, weights, f, out):
    """out [P, D] = weighted sum of f over the CSR rows ``rows`` [P]."""
    P = rows.shape[0]
    D = f.shape[1]
    for p in prange(P):
        r = rows[p]
        for c in range(D):
            out[p, c] = 0.0
        for q in range(indptr[r], indptr[r + 1]):
            g = indices[q]
            w = weights[q]
            for c in range(D):
                out[p, c] += w * f[g, c]


def _csr_rows_backward(rows, indptr, indices, weights, gout, gf):
    """gf [N, nb, Db] (zeroed) += w_q gout[p] at every g_q of row r_p; gout [P, nb, Db]: one
    thread per column block."""
    P = rows.shape[0]
    nb, Db = gout.shape[1], gout.shape[2]
    for b in prange(nb):
        for p in range(P):
            r = rows[p]
            for q in range(indptr[r], indptr[r + 1]):
                g = indices[q]
                w = weights[q]
                for c in range(Db):
                    gf[g, b, c] += w * gout[p, b, c]


CSR_ROWS = _twice(_csr_rows)
CSR_ROWS_BACKWARD = _twice(_csr_rows_backward)


class CsrRender(torch.autograd.Function):
    """features [N, D] -> [P, D] rendered at CSR rows ``rows`` of (indptr, indices, weights);
    differentiable w.r.t. the features only (the weights are frozen geometry)."""

    @staticmethod
    def forward(ctx, features, rows, indptr, indices, weights):
        f = features.detach().contiguous()
        w = weights.to(f.dtype).contiguous()
        r, ip, ix = rows.contiguous(), indptr.contiguous(), indices.contiguous()
        P, D = r.shape[0], f.shape[1]
        out = torch.empty(P, D, dtype=f.dtype)
        nnz = int((ip[r + 1] - ip[r]).sum()) if P else 0
        with numba_threads(nnz * D, PARALLEL_MIN_WORK) as nt:
            CSR_ROWS[int(nt > 1)](r.numpy(), ip.numpy(), ix.numpy(), w.numpy(), f.numpy(), out.numpy())
        ctx.save_for_backward(r, ip, ix, w)
        ctx.shape = (f.shape[0], D, nnz)
        return out

    @staticmethod
    def backward(ctx, gout):
        r, ip, ix, w = ctx.saved_tensors
        N, D, nnz = ctx.shape
        g = gout.detach().to(w.dtype).contiguous()
        grad = torch.zeros(N, D, dtype=w.dtype)
        with numba_threads(nnz * D, PARALLEL_MIN_WORK) as nt:
            nb = column_split(D, nt)
            CSR_ROWS_BACKWARD[int(nt > 1)](r.numpy(), ip.numpy(), ix.numpy(), w.numpy(),
                                           g.numpy().reshape(-1, nb, D // nb), grad.numpy().reshape(N, nb, D // nb))
        return grad, None, None, None, None
