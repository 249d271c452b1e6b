"""Fused pair terms of the mined contrastive objectives (soft, all and hard mining).

The reference (``pair_stats`` + ``soft_anchors`` + ``select_pairs`` + ``weighted_pair_losses``)
builds a dozen dense [V, V] matrices per step (C, C_F, W, upper, anchor masks, selections,
coefficients); at Np = 5000 that is ~1 GB of memory traffic and most of a training step.
This module computes the same L_pos, L_neg, n_pos, n_neg (and exact gradients) without them:

* Membership is bit-packed: ``bits [nw, V] uint64`` (nw = ceil(M / 64)), so C[i, j] is
  ``any(bits[:, i] & bits[:, j])``.
* W[i, j] is rebuilt per pair from one number per pixel (``pair_weights`` closed form:
  W = 1 + k (a_i a_j - 1) when both mean areas are > 0, else 1).
* C_F is computed by BLAS (``torch.mm``, so it honours ``torch.get_num_threads()``) one block
  of rows at a time, upper triangle only (i < j): rows [i0, i1) x columns [i0, V).
* Forward = ONE pass over the pairs. Soft/all mining: a numba kernel tests each pair once,
  setting both members' anchor flags, and accumulates per row i and per column j the
  weighted sums and counts of positive and negative pairs; since the anchor side is a single
  member (column j or row i), L = sum over pixels of anchor flag x that pixel's sums. ("either"
  needs the anchors first: a second pass.) Hard mining selects per pair: one pass.
* The forward also stores one bit per pair (C_F > 0 for soft/all: relu's gradient; hard: "pair
  selected"), packed, V (V - 1) / 16 bytes (1.5 MB at V = 5000).
* Backward = one more pass without C_F: a numba kernel writes each block's coefficients S
  (-g_pos W / Z_pos on selected positives, g_neg W / Z_neg on selected negatives with C_F > 0)
  from the bits and anchors, and two BLAS products add S fn and S^T fn to the gradient.
Memory: O(V (D + nw)) + the pair bits + one [B, V - i0] block of C_F or S (~4 MB).

Numba kernels run on min(torch threads, numba's pool) threads (one thread: a serial driver).
Pair tests and sums in the features' dtype (float32 or float64), per-pixel totals in float64;
W in float32 with the reference's exact rounding (no FMA contraction).
"""

from __future__ import annotations


import numpy as np
import torch
import torch.nn.functional as F
from numba import njit, prange

from trase.objectives.base import W_MAX, PixelSample, check_features
from trase.threads import numba_threads

# Reassociation lets numba vectorise the sums over pairs; no FMA contraction, so each pair's
# W is rounded exactly as the reference's float32 ops round it (bit-identical W).
FASTMATH = {"reassoc", "nsz", "nnan", "ninf"}
BLOCK_BYTES = 4 << 20  # target size of one [B, V] block of C_F (and of S)
PARALLEL_MIN_PIXELS = 2048  # below this V, one thread (waking numba's pool costs more than it saves)
SIDES = {"column": 0, "row": 1, "either": 2}


def pack_membership(member: np.ndarray) -> np.ndarray:
    """[V, M] bool -> [nw, V] uint64 (nw = ceil(M / 64), at least 1): bit m of pixel i's word
    m // 64 is set iff the pixel is in mask m, so C[i, j] = any(bits[:, i] & bits[:, j])."""
    V, M = member.shape
    nw = max(1, -(-M // 64))
    packed = np.packbits(member, axis=1, bitorder="little")  # [V, ceil(M/8)] uint8
    out = np.zeros((V, nw * 8), np.uint8)
    out[:, : packed.shape[1]] = packed
    return np.ascontiguousarray(out.view(np.uint64).T)  # [nw, V]


def weight_factors(mean_area: torch.Tensor) -> tuple[np.ndarray, float]:
    """[V] mean covering-mask areas -> (b [V] float32, k): W[i, j] = 1 + k (b_i b_j - 1) when
    b_i b_j > 0, else 1. Same closed form as ``pair_weights`` (b_i = max(s) / s_i, 0 where s = 0)."""
    s = mean_area.detach().to(torch.float64).reshape(-1).cpu().numpy()
    b = np.zeros(s.shape[0], np.float32)
    pos = s > 0
    if not pos.any():
        return b, 0.0
    a = s.max() / s[pos]
    hi = float(a.max()) ** 2
    if not hi > 1.0:
        return b, 0.0
    b[pos] = a.astype(np.float32)
    return b, float(np.float32((W_MAX - 1.0) / (hi - 1.0)))


PACK_MAGIC = np.uint64(0x0102040810204080)  # (8 bytes of 0/1) * magic >> 56 = those 8 bits


def _unpack_table() -> np.ndarray:
    """[256] uint64: byte value -> its 8 bits as 8 bytes of 0/1 (inverse of the magic pack)."""
    bits = (np.arange(256)[:, None] >> np.arange(8)[None, :]) & 1
    return np.ascontiguousarray(bits.astype(np.uint8)).view(np.uint64).reshape(256)


UNPACK = _unpack_table()


@njit(inline="always")
def _c_row(bits, i, j0, cr):
    """cr[k] = C[i, j0 + k] as 0/1 in cr's dtype, for k < len(cr) = V - j0."""
    nw = bits.shape[0]
    one = cr.dtype.type(1.0)
    zero = cr.dtype.type(0.0)
    x = bits[0, i]
    bw = bits[0, j0:]
    for k in range(cr.shape[0]):
        cr[k] = one if (bw[k] & x) != 0 else zero
    for w in range(1, nw):
        x = bits[w, i]
        bw = bits[w, j0:]
        for k in range(cr.shape[0]):
            if (bw[k] & x) != 0:
                cr[k] = one


@njit(inline="always")
def _pack_row(q8, q64, n, out):
    """Bytes q8[:n] of 0/1 (q64: the same buffer as uint64) -> bits out[:ceil(n / 8)]."""
    nb = (n + 7) // 8
    for k in range(n, nb * 8):
        q8[k] = 0
    for k in range(nb):
        out[k] = np.uint8((q64[k] * PACK_MAGIC) >> np.uint64(56))


# Row kernels. Each handles row i = i0 + r of a block against the columns j > i, with
# slices so that numba proves the indices non-negative and vectorises the loop over j.
# ``mat`` is the C_F block [B, V - i0] (scans) or the coefficient block S (``_coef_row``).
# They share one argument list so the two drivers below can run any of them.
ANCHOR, HARD, SELECT, COEF = 0, 1, 2, 3


@njit(inline="always")
def _row_setup(mat, r, i0, bits, b, cr_all):
    """Row i = i0 + r against columns j >= j0 = i + 1: -> (i, j0, cr = C[i, j0:] as 0/1,
    v_ = the row's block entries from j0, b_ = b[j0:], b[i])."""
    i = i0 + r
    j0 = i + 1
    cr = cr_all[j0:]
    _c_row(bits, i, j0, cr)
    return i, j0, cr, mat[r, j0 - i0:], b[j0:], b[i]


@njit(inline="always")
def _pair_weight(bi, bj, kw, one):
    """W_ij from the closed form of base.pair_weights: 1 + kw (a_i a_j - 1), 1 where an area is 0."""
    p = bi * bj
    return one + kw * (p - one) if p > 0 else one


@njit(fastmath=FASTMATH, cache=True, nogil=True)
def _anchor_row(mat, r, i0, bits, b, kw, tp, tn, cr_all, col, rows, qbits, qoff, q64):
    """Soft/all mining scan. Adds to row i (``rows[i]``) and to each column j (``col[:, j]``)
    0: sum of W C_F over positive pairs (C = 1), 1: sum of W relu(C_F) over negative pairs,
    2: number of positive pairs, 3: imperfect positives (C = 1, C_F < tp), 4: imperfect
    negatives (C = 0, C_F > tn). Stores the bit C_F > 0 of each pair for the backward."""
    V = bits.shape[1]
    one = b.dtype.type(1.0)
    zero = mat.dtype.type(0.0)
    q8 = q64.view(np.uint8)
    i, j0, cr, v_, b_, bi = _row_setup(mat, r, i0, bits, b, cr_all)
    n = V - j0
    p0, p1, p2, p3, p4 = col[0, j0:], col[1, j0:], col[2, j0:], col[3, j0:], col[4, j0:]
    s0 = zero
    s1 = zero
    s2 = zero
    s3 = zero
    s4 = zero
    for k in range(n):
        v = v_[k]
        c = cr[k]
        wt = _pair_weight(bi, b_[k], kw, one)
        wv = wt * v
        pv = c * wv
        nv = wv - pv if v > zero else zero
        ip = c if v < tp else zero
        iq = (1 - c) if v > tn else zero
        q8[k] = v > zero
        s0 += pv
        s1 += nv
        s2 += c
        s3 += ip
        s4 += iq
        p0[k] += pv
        p1[k] += nv
        p2[k] += c
        p3[k] += ip
        p4[k] += iq
    rows[i, 0] += s0
    rows[i, 1] += s1
    rows[i, 2] += s2
    rows[i, 3] += s3
    rows[i, 4] += s4
    _pack_row(q8, q64, n, qbits[qoff[i]:])


@njit(fastmath=FASTMATH, cache=True, nogil=True)
def _hard_row(mat, r, i0, bits, b, kw, tp, tn, cr_all, rows, qbits, qoff, q64):
    """Hard mining scan: rows[i] 0: sum of W C_F over selected positives (C = 1, C_F < tp),
    1: sum of W relu(C_F) over selected negatives (C = 0, C_F > tn), 2, 3: their counts.
    Stores the bit "pair has a nonzero coefficient" for the backward."""
    V = bits.shape[1]
    one = b.dtype.type(1.0)
    zero = mat.dtype.type(0.0)
    q8 = q64.view(np.uint8)
    i, j0, cr, v_, b_, bi = _row_setup(mat, r, i0, bits, b, cr_all)
    n = V - j0
    s0 = zero
    s1 = zero
    s2 = zero
    s3 = zero
    for k in range(n):
        v = v_[k]
        c = cr[k]
        wt = _pair_weight(bi, b_[k], kw, one)
        sp = c if v < tp else zero
        sn = (1 - c) if v > tn else zero
        rl = sn if v > zero else zero
        s0 += sp * wt * v
        s1 += rl * wt * v
        s2 += sp
        s3 += sn
        q8[k] = (sp + rl) > zero
    rows[i, 0] += s0
    rows[i, 1] += s1
    rows[i, 2] += s2
    rows[i, 3] += s3
    _pack_row(q8, q64, n, qbits[qoff[i]:])


@njit(fastmath=FASTMATH, cache=True, nogil=True)
def _select_row(mat, r, i0, bits, b, kw, posA, negA, wc, wr, cr_all, rows):
    """Anchors known: rows[i] 0: sum of W C_F over selected positives, 1: sum of W relu(C_F)
    over selected negatives, 2, 3: their counts. A pair (i, j)'s anchor flag is
    1 - (1 - wc A_j)(1 - wr A_i) (column side: wc = 1; row: wr = 1; either: both)."""
    one = b.dtype.type(1.0)
    zero = mat.dtype.type(0.0)
    i, j0, cr, v_, b_, bi = _row_setup(mat, r, i0, bits, b, cr_all)
    pa = posA[j0:]
    na = negA[j0:]
    rp = 1 - wr * posA[i]
    rn = 1 - wr * negA[i]
    s0 = zero
    s1 = zero
    s2 = zero
    s3 = zero
    for k in range(cr.shape[0]):
        v = v_[k]
        c = cr[k]
        wt = _pair_weight(bi, b_[k], kw, one)
        sp = c * (1 - (1 - wc * pa[k]) * rp)
        sn = (1 - c) * (1 - (1 - wc * na[k]) * rn)
        s0 += sp * wt * v
        s1 += sn * wt * v if v > zero else zero
        s2 += sp
        s3 += sn
    rows[i, 0] += s0
    rows[i, 1] += s1
    rows[i, 2] += s2
    rows[i, 3] += s3


@njit(fastmath=FASTMATH, cache=True, nogil=True)
def _coef_row(mat, r, i0, bits, b, kw, posA, negA, wc, wr, qpos, cpos, cneg, cr_all, qbits, qoff, q64, table):
    """Row r of the coefficient block S = ``mat``: S[r, j - i0] = cpos W on selected positives,
    cneg W on selected negatives with C_F > 0 (relu's gradient), 0 elsewhere (j <= i too).
    Selection: anchors as ``_select_row`` and the stored bit q (soft: C_F > 0, applied to the
    negatives; hard, qpos = 1, anchors all 1: the whole selection)."""
    V = bits.shape[1]
    one = b.dtype.type(1.0)
    zero = mat.dtype.type(0.0)
    q8 = q64.view(np.uint8)
    i = i0 + r
    j0 = i + 1
    n = V - j0
    lower = mat[r, : j0 - i0]
    for k in range(lower.shape[0]):
        lower[k] = zero
    if n == 0:
        return
    s_ = mat[r, j0 - i0:]
    cr = cr_all[j0:]
    _c_row(bits, i, j0, cr)
    qb = qbits[qoff[i]:]
    for k in range((n + 7) // 8):
        q64[k] = table[qb[k]]
    b_ = b[j0:]
    pa = posA[j0:]
    na = negA[j0:]
    bi = b[i]
    rp = 1 - wr * posA[i]
    rn = 1 - wr * negA[i]
    for k in range(n):
        c = cr[k]
        q = mat.dtype.type(q8[k])
        wt = _pair_weight(bi, b_[k], kw, one)
        sp = c * (1 - (1 - wc * pa[k]) * rp) * (qpos * q + (1 - qpos))
        sn = (1 - c) * (1 - (1 - wc * na[k]) * rn) * q
        s_[k] = wt * (cpos * sp + cneg * sn)


@njit(cache=True, nogil=True)
def _run_row(kind, mat, r, i0, bits, b, kw, tp, tn, posA, negA, wc, wr, qpos, cpos, cneg, table,
             crow, col, rows, qbits, qoff, q64):
    if kind == ANCHOR:
        _anchor_row(mat, r, i0, bits, b, kw, tp, tn, crow, col, rows, qbits, qoff, q64)
    elif kind == HARD:
        _hard_row(mat, r, i0, bits, b, kw, tp, tn, crow, rows, qbits, qoff, q64)
    elif kind == SELECT:
        _select_row(mat, r, i0, bits, b, kw, posA, negA, wc, wr, crow, rows)
    else:
        _coef_row(mat, r, i0, bits, b, kw, posA, negA, wc, wr, qpos, cpos, cneg, crow, qbits, qoff, q64, table)


@njit(cache=True, nogil=True)
def _rows_serial(kind, mat, i0, bits, b, kw, tp, tn, posA, negA, wc, wr, qpos, cpos, cneg, table,
                 crow, cols, rows, qbits, qoff, qbuf):
    """All rows of a block on the calling thread. (One thread does not go through numba's
    parallel pool: on a loaded machine waking the pool cost ~10 ms per call, measured.)"""
    for r in range(mat.shape[0]):
        _run_row(kind, mat, r, i0, bits, b, kw, tp, tn, posA, negA, wc, wr, qpos, cpos, cneg, table,
                 crow[0], cols[0], rows, qbits, qoff, qbuf[0])


@njit(parallel=True, cache=True, nogil=True)
def _rows_parallel(kind, mat, i0, bits, b, kw, tp, tn, posA, negA, wc, wr, qpos, cpos, cneg, table,
                   crow, cols, rows, qbits, qoff, qbuf):
    """The rows of a block split into T = crow.shape[0] contiguous chunks, one per thread,
    each with its own scratch row and column accumulators (``cols[t]``); rows are disjoint."""
    B = mat.shape[0]
    T = crow.shape[0]
    per = (B + T - 1) // T
    for t in prange(T):
        for r in range(t * per, min(B, (t + 1) * per)):
            _run_row(kind, mat, r, i0, bits, b, kw, tp, tn, posA, negA, wc, wr, qpos, cpos, cneg, table,
                     crow[t], cols[t], rows, qbits, qoff, qbuf[t])


class _Plan:
    """Everything about one objective evaluation except the features: membership bits, weight
    factors, thresholds, selection rule. The forward fills in anchors, counts, Z and the packed
    per-pair bits the backward needs (V (V - 1) / 16 bytes: 1.5 MB at V = 5000)."""

    def __init__(self, bits, b, kw, hard, tp, tn, side, normalise):
        self.bits, self.b, self.kw = bits, b, np.float32(kw)
        self.hard, self.tp, self.tn = bool(hard), float(tp), float(tn)
        self.side, self.normalise = side, normalise
        V = bits.shape[1]
        self.posA = np.zeros(V, np.float32)
        self.negA = np.zeros(V, np.float32)
        self.n_pos = self.n_neg = 0
        self.z_pos = self.z_neg = 1
        nbytes = (V - 1 - np.arange(V) + 7) // 8  # [V] packed bytes of row i (j > i)
        self.qoff = np.zeros(V + 1, np.int64)
        np.cumsum(nbytes, out=self.qoff[1:])
        self.qbits = np.zeros(int(self.qoff[-1]) + 8, np.uint8)

    def _selection(self, dt):
        """(wc, wr, qpos, posA, negA) of the selection rule; hard: every pair 'anchored', the
        stored bit is the whole selection."""
        if self.hard:
            ones = np.ones(self.posA.shape[0], dt)
            return dt(1.0), dt(0.0), dt(1.0), ones, ones
        wc = 1.0 if self.side in ("column", "either") else 0.0
        wr = 1.0 if self.side in ("row", "either") else 0.0
        return dt(wc), dt(wr), dt(0.0), self.posA.astype(dt), self.negA.astype(dt)

    def _pass(self, kind: int, fn: torch.Tensor, n_cols: int = 0, coef=(0.0, 0.0), grad=None):
        """Run row kernel ``kind`` over the upper triangle, one block of rows at a time.

        Scans (ANCHOR, HARD, SELECT) get the block's C_F by BLAS; COEF gets an empty block that
        the kernel fills with coefficients S, then grad += S fn[i0:] and grad[i0:] += S^T fn[rows]
        (BLAS). Returns (rows [V, 5] per-row results, cols [5, V] per-column results)."""
        V, _ = fn.shape
        dt = np.float32 if fn.dtype == torch.float32 else np.float64
        B = int(min(V, max(32, BLOCK_BYTES // max(V * fn.element_size(), 1))))
        wc, wr, qpos, posA, negA = self._selection(dt)
        rows = np.zeros((V, 5), dt)
        with numba_threads(V, PARALLEL_MIN_PIXELS) as T:
            crow = np.zeros((T, V), dt)
            cols = np.zeros((T, n_cols, V), dt)
            qbuf = np.zeros((T, (V + 7) // 8 + 1), np.uint64)
            run = _rows_serial if T == 1 else _rows_parallel
            buf = torch.empty(B * V, dtype=fn.dtype)  # one block of C_F or S, reused
            for i0 in range(0, V, B):
                i1 = min(V, i0 + B)
                mat = buf[: (i1 - i0) * (V - i0)].view(i1 - i0, V - i0)
                if kind != COEF:
                    torch.mm(fn[i0:i1], fn[i0:].T, out=mat)  # [B, V - i0] C_F block
                run(kind, mat.numpy(), i0, self.bits, self.b, self.kw, dt(self.tp), dt(self.tn), posA, negA,
                    wc, wr, qpos, dt(coef[0]), dt(coef[1]), UNPACK, crow, cols, rows, self.qbits, self.qoff, qbuf)
                if grad is not None:
                    grad[i0:i1].addmm_(mat, fn[i0:])
                    grad[i0:].addmm_(mat.T, fn[i0:i1])
        return rows.astype(np.float64), cols.sum(axis=0, dtype=np.float64)

    def forward(self, fn: torch.Tensor) -> tuple[float, float]:
        """fn [V, D] normalised features -> (sum of W C_F over selected positives, sum of
        W relu(C_F) over selected negatives); sets anchors, counts and Z."""
        V = fn.shape[0]
        if V < 2:
            return 0.0, 0.0
        if self.hard:
            rows, _ = self._pass(HARD, fn)
            self.n_pos, self.n_neg = int(np.rint(rows[:, 2].sum())), int(np.rint(rows[:, 3].sum()))
            self.z_pos, self.z_neg = max(self.n_pos, 1), max(self.n_neg, 1)
            return float(rows[:, 0].sum()), float(rows[:, 1].sum())
        rows, col = self._pass(ANCHOR, fn, n_cols=5)
        row = rows.T  # [5, V]
        pa = (row[3] + col[3]) > 0  # [V] anchors: an imperfect partner on either side
        na = (row[4] + col[4]) > 0
        self.posA, self.negA = pa.astype(np.float32), na.astype(np.float32)
        idx = np.arange(V)
        if self.side == "column":  # pair (i, j) belongs to its column j: partners i < j
            sp, sn = col[0][pa].sum(), col[1][na].sum()
            n_pos = int(np.rint(col[2][pa].sum()))
            n_neg = int(np.rint((idx - col[2])[na].sum()))
            z_pos, z_neg = int(idx[pa].sum()), int(idx[na].sum())
        elif self.side == "row":  # pair (i, j) belongs to its row i: partners j > i
            sp, sn = row[0][pa].sum(), row[1][na].sum()
            n_pos = int(np.rint(row[2][pa].sum()))
            n_neg = int(np.rint((V - 1 - idx - row[2])[na].sum()))
            z_pos, z_neg = int((V - 1 - idx)[pa].sum()), int((V - 1 - idx)[na].sum())
        else:  # either member: not separable per pixel, a second pass with the anchors known
            sel, _ = self._pass(SELECT, fn)
            sp, sn = sel[:, 0].sum(), sel[:, 1].sum()
            n_pos, n_neg = int(np.rint(sel[:, 2].sum())), int(np.rint(sel[:, 3].sum()))
            total = V * (V - 1) // 2
            kp, kn = V - int(pa.sum()), V - int(na.sum())
            z_pos, z_neg = total - kp * (kp - 1) // 2, total - kn * (kn - 1) // 2
        self.n_pos, self.n_neg = n_pos, n_neg
        if self.normalise == "selected":
            z_pos, z_neg = n_pos, n_neg
        self.z_pos, self.z_neg = max(z_pos, 1), max(z_neg, 1)
        return float(sp), float(sn)

    def gradient(self, fn: torch.Tensor, g_pos: float, g_neg: float) -> torch.Tensor:
        """d(g_pos L_pos + g_neg L_neg) / d fn [V, D]: per block of rows, the coefficients S
        (from the stored bits, no C_F recomputation) and grad += S fn + S^T fn (BLAS)."""
        grad = torch.zeros_like(fn)
        if fn.shape[0] < 2 or (g_pos == 0.0 and g_neg == 0.0):
            return grad
        self._pass(COEF, fn, coef=(-g_pos / self.z_pos, g_neg / self.z_neg), grad=grad)
        return grad


class _PairLosses(torch.autograd.Function):
    """fn [V, D] -> (L_pos, L_neg) with the selection of ``plan`` (filled in by the forward)."""

    @staticmethod
    def forward(ctx, fn, plan):
        fn = fn.contiguous()
        sp, sn = plan.forward(fn)
        ctx.plan = plan
        ctx.save_for_backward(fn)
        return fn.new_tensor(-sp / plan.z_pos), fn.new_tensor(sn / plan.z_neg)

    @staticmethod
    def backward(ctx, g_pos, g_neg):
        (fn,) = ctx.saved_tensors
        return ctx.plan.gradient(fn, float(g_pos), float(g_neg)), None


def fused_pair_losses(
    features: torch.Tensor,
    sample: PixelSample,
    *,
    hard: bool = False,
    tau_pos: float,
    tau_neg: float,
    side: str = "column",
    normalise: str = "anchor_pairs",
) -> tuple[torch.Tensor, torch.Tensor, int, int, int]:
    """features [Np, D] -> (L_pos, L_neg, n_pos, n_neg, n_valid), equal to the reference
    (``pair_stats`` + anchors + ``select_pairs`` + ``weighted_pair_losses``) for

    * ``hard=False``: anchors = pixels with a partner k != a with C = 1 and C_F < tau_pos
      (positive) / C = 0 and C_F > tau_neg (negative); tau_pos = inf, tau_neg = -inf give
      "all" mining; ``side`` and ``normalise`` as ``SoftMining``;
    * ``hard=True``: the individually violating pairs, each term divided by its pair count.
    """
    check_features(features, sample)
    if side not in SIDES:
        raise ValueError(f"anchor side must be one of {tuple(SIDES)}, got {side!r}")
    member = sample.membership
    valid = member.any(dim=1)  # [Np]
    fn = F.normalize(features[valid], dim=1, eps=1e-12)  # [V, D]; zero features stay zero
    bits = pack_membership(member[valid].cpu().numpy())
    b, kw = weight_factors(sample.pixel_mean_area[valid])
    plan = _Plan(bits, b, kw, hard, tau_pos, tau_neg, side, normalise)
    if fn.device.type != "cpu":
        raise ValueError("the fused pair losses run on CPU tensors; use impl='reference' on other devices")
    l_pos, l_neg = _PairLosses.apply(fn, plan)
    return l_pos, l_neg, plan.n_pos, plan.n_neg, int(valid.sum())
