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
  (-g_pos W C / Z_pos on selected positives, g_neg W (1 - C) / Z_neg on selected negatives with
  C_F > 0) from the bits and anchors, and two BLAS products add S fn and S^T fn to the gradient.
* The soft correspondence (``correspondence="jaccard"``, soft and all mining): C of a pair is
  its shared membership bits over the two pixels' counts, recomputed per pair from the bits;
  C is 0/1 otherwise, and the kernels' soft-only work is compiled out (``cnt`` None).
Memory: O(V (D + nw)) + the pair bits + one [B, V - i0] block of C_F or S (~4 MB).

Numba kernels run on min(torch threads, numba's pool) threads (one thread: a serial driver).
Pair tests and sums in the features' dtype (float32 or float64), per-pixel totals in float64;
W in float32 with the reference's exact rounding (no FMA contraction). The numba kernels
live in ``fused_kernels``.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from trase.objectives.base import CORRESPONDENCES, PixelSample, check_features
from trase.objectives.fused_kernels import (
    ANCHOR,
    COEF,
    HARD,
    SELECT,
    UNPACK,
    pack_membership,
    rows_parallel,
    rows_serial,
    weight_factors,
)
from trase.threads import numba_threads

BLOCK_BYTES = 4 << 20  # target size of one [B, V] block of C_F (and of S)
PARALLEL_MIN_PIXELS = 2048  # below this V, one thread (waking numba's pool costs more than it saves)
SIDES = {"column": 0, "row": 1, "either": 2}


class _Plan:
    """Everything about one objective evaluation except the features: membership bits, weight
    factors, thresholds, selection rule. The forward fills in anchors, counts, Z and the packed
    per-pair bits the backward needs (V (V - 1) / 16 bytes: 1.5 MB at V = 5000)."""

    def __init__(self, bits, cnt, b, kw, hard, tp, tn, side, normalise):
        self.bits, self.cnt, self.b, self.kw = bits, cnt, b, np.float32(kw)
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
        (BLAS). Returns (rows [V, 6] per-row results, cols [n_cols, V] per-column results)."""
        V, _ = fn.shape
        dt = np.float32 if fn.dtype == torch.float32 else np.float64
        B = int(min(V, max(32, BLOCK_BYTES // max(V * fn.element_size(), 1))))
        wc, wr, qpos, posA, negA = self._selection(dt)
        rows = np.zeros((V, 6), dt)
        with numba_threads(V, PARALLEL_MIN_PIXELS) as T:
            crow = np.zeros((T, V), dt)
            cols = np.zeros((T, n_cols, V), dt)
            qbuf = np.zeros((T, (V + 7) // 8 + 1), np.uint64)
            run = rows_serial if T == 1 else rows_parallel
            buf = torch.empty(B * V, dtype=fn.dtype)  # one block of C_F or S, reused
            for i0 in range(0, V, B):
                i1 = min(V, i0 + B)
                mat = buf[: (i1 - i0) * (V - i0)].view(i1 - i0, V - i0)
                if kind != COEF:
                    torch.mm(fn[i0:i1], fn[i0:].T, out=mat)  # [B, V - i0] C_F block
                run(kind, mat.numpy(), i0, self.bits, self.cnt, self.b, self.kw, dt(self.tp), dt(self.tn), posA, negA,
                    wc, wr, qpos, dt(coef[0]), dt(coef[1]), UNPACK, crow, cols, rows, self.qbits, self.qoff, qbuf)
                if grad is not None:
                    grad[i0:i1].addmm_(mat, fn[i0:])
                    grad[i0:].addmm_(mat.T, fn[i0:i1])
        return rows.astype(np.float64), cols.sum(axis=0, dtype=np.float64)

    def forward(self, fn: torch.Tensor) -> tuple[float, float]:
        """fn [V, D] normalised features -> (sum of W C C_F over selected positives, sum of
        W (1 - C) relu(C_F) over selected negatives); sets anchors, counts and Z."""
        V = fn.shape[0]
        if V < 2:
            return 0.0, 0.0
        if self.hard:
            rows, _ = self._pass(HARD, fn)
            self.n_pos, self.n_neg = int(np.rint(rows[:, 2].sum())), int(np.rint(rows[:, 3].sum()))
            self.z_pos, self.z_neg = max(self.n_pos, 1), max(self.n_neg, 1)
            return float(rows[:, 0].sum()), float(rows[:, 1].sum())
        rows, col = self._pass(ANCHOR, fn, n_cols=6)
        row = rows.T  # [6, V]
        soft = self.cnt is not None
        pa = (row[3] + col[3]) > 0  # [V] anchors: an imperfect partner on either side
        na = (row[4] + col[4]) > 0
        self.posA, self.negA = pa.astype(np.float32), na.astype(np.float32)
        idx = np.arange(V)
        if self.side == "column":  # pair (i, j) belongs to its column j: partners i < j
            sp, sn = col[0][pa].sum(), col[1][na].sum()
            n_pos = int(np.rint(col[2][pa].sum()))
            n_neg = int(np.rint((col[5] if soft else idx - col[2])[na].sum()))
            z_pos, z_neg = int(idx[pa].sum()), int(idx[na].sum())
        elif self.side == "row":  # pair (i, j) belongs to its row i: partners j > i
            sp, sn = row[0][pa].sum(), row[1][na].sum()
            n_pos = int(np.rint(row[2][pa].sum()))
            n_neg = int(np.rint((row[5] if soft else V - 1 - idx - row[2])[na].sum()))
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
    correspondence: str = "binary",
) -> tuple[torch.Tensor, torch.Tensor, int, int, int]:
    """features [Np, D] -> (L_pos, L_neg, n_pos, n_neg, n_valid), equal to the reference
    (``pair_stats`` + anchors + ``select_pairs`` + ``weighted_pair_losses``) for

    * ``hard=False``: anchors = pixels with a partner k != a with C = 1 and C_F < tau_pos
      (positive) / C = 0 and C_F > tau_neg (negative); tau_pos = inf, tau_neg = -inf give
      "all" mining; ``side`` and ``normalise`` as ``SoftMining``;
    * ``hard=True``: the individually violating pairs, each term divided by its pair count.

    ``correspondence="jaccard"`` (soft and all mining): the soft C of ``base.mask_jaccard``;
    positives are the pairs with C > 0 (weighted W C), negatives those with C < 1 (W (1 - C)).
    """
    check_features(features, sample)
    if side not in SIDES:
        raise ValueError(f"anchor side must be one of {tuple(SIDES)}, got {side!r}")
    member = sample.membership
    valid = member.any(dim=1)  # [Np]
    fn = F.normalize(features[valid], dim=1, eps=1e-12)  # [V, D]; zero features stay zero
    if correspondence not in CORRESPONDENCES or (hard and correspondence != "binary"):
        raise ValueError(f"correspondence {correspondence!r}: one of {CORRESPONDENCES}, and 'binary' for hard mining")
    member_np = member[valid].cpu().numpy()
    bits = pack_membership(member_np)
    soft = correspondence == "jaccard"
    cnt = member_np.sum(axis=1).astype(np.float32) if soft else None  # [V] masks per pixel
    b, kw = weight_factors(sample.pixel_mean_area[valid])
    plan = _Plan(bits, cnt, b, kw, hard, tau_pos, tau_neg, side, normalise)
    if fn.device.type != "cpu":
        raise ValueError("the fused pair losses run on CPU tensors; use impl='reference' on other devices")
    l_pos, l_neg = _PairLosses.apply(fn, plan)
    return l_pos, l_neg, plan.n_pos, plan.n_neg, int(valid.sum())
