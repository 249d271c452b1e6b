"""Numba kernels of the fused pair terms (``trase.objectives.fused``): membership bit
packing, per-pixel weight factors, and the per-row passes over the pairs (soft/all-mining
anchors and sums, hard-mining selection, the backward's coefficients). One row of the upper
triangle per call; ``rows_serial`` / ``rows_parallel`` drive them over a block of rows."""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange

from trase.objectives.base import W_MAX

# Reassociation lets numba vectorise the sums over pairs; no FMA contraction, so each pair's
# W is rounded exactly as the reference's float32 ops round it (bit-identical W).
FASTMATH = {"reassoc", "nsz", "nnan", "ninf"}


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
def _popcount(x):
    """Set bits of a uint64: the SWAR count with shifts and adds only (numba has no popcount
    intrinsic, and AVX2 has no vector 64-bit multiply)."""
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    x = x + (x >> np.uint64(8))
    x = x + (x >> np.uint64(16))
    x = x + (x >> np.uint64(32))
    return x & np.uint64(0x7F)


@njit(inline="always")
def _jaccard_row(bits, cnt, i, j0, cr):
    """cr[k] = shared masks / masks covering i or j0 + k (the soft C, rounded in float32 as
    ``base.mask_jaccard`` rounds it); ``cnt`` [V] float32 masks per pixel."""
    nw = bits.shape[0]
    x = bits[0, i]
    bw = bits[0, j0:]
    for k in range(cr.shape[0]):
        cr[k] = _popcount(bw[k] & x)
    for w in range(1, nw):
        x = bits[w, i]
        bw = bits[w, j0:]
        for k in range(cr.shape[0]):
            cr[k] += _popcount(bw[k] & x)
    ci = cnt[i]
    cj = cnt[j0:]
    for k in range(cr.shape[0]):
        sh = np.float32(cr[k])  # a count: exact
        cr[k] = sh / ((ci + cj[k]) - sh)


@njit(inline="always")
def _c_row(bits, cnt, i, j0, cr):
    """cr[k] = C[i, j0 + k] in cr's dtype, for k < len(cr) = V - j0: 0/1 when ``cnt`` is None
    (the binary C; numba prunes the other branch), else the soft C (``_jaccard_row``)."""
    if cnt is not None:
        _jaccard_row(bits, cnt, i, j0, cr)
        return
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
def _row_setup(mat, r, i0, bits, cnt, b, cr_all):
    """Row i = i0 + r against columns j >= j0 = i + 1: -> (i, j0, cr = C[i, j0:],
    v_ = the row's block entries from j0, b_ = b[j0:], b[i])."""
    i = i0 + r
    j0 = i + 1
    cr = cr_all[j0:]
    _c_row(bits, cnt, i, j0, cr)
    return i, j0, cr, mat[r, j0 - i0:], b[j0:], b[i]


@njit(inline="always")
def _pair_weight(bi, bj, kw, one):
    """W_ij from the closed form of base.pair_weights: 1 + kw (a_i a_j - 1), 1 where an area is 0."""
    p = bi * bj
    return one + kw * (p - one) if p > 0 else one


@njit(fastmath=FASTMATH, cache=True, nogil=True)
def _anchor_row(mat, r, i0, bits, cnt, b, kw, tp, tn, cr_all, col, rows, qbits, qoff, q64):
    """Soft/all mining scan. Adds to row i (``rows[i]``) and to each column j (``col[:, j]``)
    0: sum of W C C_F over positive pairs (C > 0), 1: sum of W (1 - C) relu(C_F) over negative
    pairs (C < 1), 2: number of positive pairs, 3: imperfect positives (C > 0, C_F < tp; > 0
    marks one), 4: imperfect negatives (C < 1, C_F > tn), 5: number of negative pairs.
    Stores the bit C_F > 0 of each pair for the backward."""
    V = bits.shape[1]
    one = b.dtype.type(1.0)
    zero = mat.dtype.type(0.0)
    q8 = q64.view(np.uint8)
    i, j0, cr, v_, b_, bi = _row_setup(mat, r, i0, bits, cnt, b, cr_all)
    n = V - j0
    p0, p1, p2, p3, p4, p5 = col[0, j0:], col[1, j0:], col[2, j0:], col[3, j0:], col[4, j0:], col[5, j0:]
    s0 = zero
    s1 = zero
    s2 = zero
    s3 = zero
    s4 = zero
    s5 = zero
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
        s3 += ip
        s4 += iq
        p0[k] += pv
        p1[k] += nv
        p3[k] += ip
        p4[k] += iq
        if cnt is None:  # binary C: c is the pair's count, and its negatives are the rest
            s2 += c
            p2[k] += c
        else:
            np_ = one if c > zero else zero
            nn_ = one if c < one else zero
            s2 += np_
            s5 += nn_
            p2[k] += np_
            p5[k] += nn_
    rows[i, 0] += s0
    rows[i, 1] += s1
    rows[i, 2] += s2
    rows[i, 3] += s3
    rows[i, 4] += s4
    rows[i, 5] += s5
    _pack_row(q8, q64, n, qbits[qoff[i]:])


@njit(fastmath=FASTMATH, cache=True, nogil=True)
def _hard_row(mat, r, i0, bits, cnt, b, kw, tp, tn, cr_all, rows, qbits, qoff, q64):
    """Hard mining scan: rows[i] 0: sum of W C_F over selected positives (C = 1, C_F < tp),
    1: sum of W relu(C_F) over selected negatives (C = 0, C_F > tn), 2, 3: their counts.
    Stores the bit "pair has a nonzero coefficient" for the backward. Binary C only."""
    V = bits.shape[1]
    one = b.dtype.type(1.0)
    zero = mat.dtype.type(0.0)
    q8 = q64.view(np.uint8)
    i, j0, cr, v_, b_, bi = _row_setup(mat, r, i0, bits, cnt, b, cr_all)
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
def _select_row(mat, r, i0, bits, cnt, b, kw, posA, negA, wc, wr, cr_all, rows):
    """Anchors known: rows[i] 0: sum of W C C_F over selected positives, 1: sum of
    W (1 - C) relu(C_F) over selected negatives, 2, 3: their counts. A pair (i, j)'s anchor
    flag is 1 - (1 - wc A_j)(1 - wr A_i) (column side: wc = 1; row: wr = 1; either: both)."""
    one = b.dtype.type(1.0)
    zero = mat.dtype.type(0.0)
    i, j0, cr, v_, b_, bi = _row_setup(mat, r, i0, bits, cnt, b, cr_all)
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
        ap = 1 - (1 - wc * pa[k]) * rp
        an = 1 - (1 - wc * na[k]) * rn
        sp = c * ap
        sn = (1 - c) * an
        s0 += sp * wt * v
        s1 += sn * wt * v if v > zero else zero
        if cnt is None:
            s2 += sp
            s3 += sn
        else:
            s2 += ap if c > zero else zero
            s3 += an if c < one else zero
    rows[i, 0] += s0
    rows[i, 1] += s1
    rows[i, 2] += s2
    rows[i, 3] += s3


@njit(fastmath=FASTMATH, cache=True, nogil=True)
def _coef_row(mat, r, i0, bits, cnt, b, kw, posA, negA, wc, wr, qpos, cpos, cneg, cr_all, qbits, qoff, q64, table):
    """Row r of the coefficient block S = ``mat``: S[r, j - i0] = cpos W C on selected positives,
    cneg W (1 - C) on selected negatives with C_F > 0 (relu's gradient), 0 elsewhere (j <= i too).
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
    _c_row(bits, cnt, i, j0, cr)
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
def _run_row(kind, mat, r, i0, bits, cnt, b, kw, tp, tn, posA, negA, wc, wr, qpos, cpos, cneg, table,
             crow, col, rows, qbits, qoff, q64):
    if kind == ANCHOR:
        _anchor_row(mat, r, i0, bits, cnt, b, kw, tp, tn, crow, col, rows, qbits, qoff, q64)
    elif kind == HARD:
        _hard_row(mat, r, i0, bits, cnt, b, kw, tp, tn, crow, rows, qbits, qoff, q64)
    elif kind == SELECT:
        _select_row(mat, r, i0, bits, cnt, b, kw, posA, negA, wc, wr, crow, rows)
    else:
        _coef_row(mat, r, i0, bits, cnt, b, kw, posA, negA, wc, wr, qpos, cpos, cneg, crow, qbits, qoff, q64,
                  table)


@njit(cache=True, nogil=True)
def rows_serial(kind, mat, i0, bits, cnt, b, kw, tp, tn, posA, negA, wc, wr, qpos, cpos, cneg, table,
                 crow, cols, rows, qbits, qoff, qbuf):
    """All rows of a block on the calling thread. (One thread does not go through numba's
    parallel pool: on a loaded machine waking the pool cost ~10 ms per call, measured.)"""
    for r in range(mat.shape[0]):
        _run_row(kind, mat, r, i0, bits, cnt, b, kw, tp, tn, posA, negA, wc, wr, qpos, cpos, cneg, table,
                 crow[0], cols[0], rows, qbits, qoff, qbuf[0])


@njit(parallel=True, cache=True, nogil=True)
def rows_parallel(kind, mat, i0, bits, cnt, b, kw, tp, tn, posA, negA, wc, wr, qpos, cpos, cneg, table,
                   crow, cols, rows, qbits, qoff, qbuf):
    """The rows of a block split into T = crow.shape[0] contiguous chunks, one per thread,
    each with its own scratch row and column accumulators (``cols[t]``); rows are disjoint."""
    B = mat.shape[0]
    T = crow.shape[0]
    per = (B + T - 1) // T
    for t in prange(T):
        for r in range(t * per, min(B, (t + 1) * per)):
            _run_row(kind, mat, r, i0, bits, cnt, b, kw, tp, tn, posA, negA, wc, wr, qpos, cpos, cneg, table,
                     crow[t], cols[t], rows, qbits, qoff, qbuf[t])
