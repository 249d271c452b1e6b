"""TRASE's soft-mined contrastive objective (paper Sec. 3.2), plus the anchor/selection helpers
that the "hard" and "all" mining baselines reuse.

Exact choices (the paper's equations and the public code differ in details):

* Pixels in no *sampled* mask are dropped from the pair terms (``pair_stats``, see base.py).
  They still count in the norm regulariser.
* Anchors. Pixel ``a`` is a positive anchor if some *other* valid pixel ``k != a`` has
  C[a, k] = 1 and C_F[a, k] < tau_p; a negative anchor if some ``k != a`` has C[a, k] = 0 and
  C_F[a, k] > tau_n. The diagonal is excluded (the public code includes it; with dropped
  no-mask pixels it only matters for zero-norm features, where C_F[a, a] = 0 would make the
  pixel a positive anchor by itself).
* Anchor side. C and C_F are symmetric, so the existential test is the same over rows or
  columns; what differs is *which member of the pair (i < j)* must be the anchor. The paper
  writes M_ij = anchor(i) & (i < j) (rows); the public code ORs over dim 0 and masks columns,
  i.e. M_ij = anchor(j) & (i < j). Default ``"column"`` follows the public code; ``"row"``
  follows the paper, ``"either"`` uses anchor(i) | anchor(j). Sampled pixels are in random
  order, so row and column are statistically equivalent.
* Selected positives: C & upper & anchor_pos; selected negatives: ~C & upper & anchor_neg.
* Normalisation Z (``normalise``): ``"anchor_pairs"`` (default, the public code) divides each
  term by the number of upper-triangle pairs whose anchor side is an anchor of that term's
  kind (positive *and* negative pairs of those anchors, i.e. "the total number of pixel pairs"
  considered); ``"selected"`` divides by the number of selected pairs of that term. Z is
  clamped to >= 1 so an empty selection gives a zero (not NaN) term.
* L = L_pos + L_neg + reg_weight * (1 - mean ||F(p)||)^2 with reg_weight = 1.
* Correspondence (``correspondence``): ``"binary"`` (the paper's C: 1 iff two pixels share a
  sampled mask) or ``"jaccard"``, the soft C the paper's limitations section proposes for small
  objects that a larger mask also covers: C = |shared masks| / |masks covering either pixel|.
  A pair counts as positive with weight W C where C > 0 and as negative with weight W (1 - C)
  where C < 1; the anchor tests read C > 0 and C < 1. With every C in {0, 1} it is the binary
  rule.

Implementations (``impl``): ``"fused"`` (``trase.objectives.fused``: bit-packed membership,
blockwise BLAS C_F, numba pair kernels, O(V (D + M / 64)) memory, a custom autograd Function)
and ``"reference"`` (the dense [V, V] torch matrices below, kept readable; the tests compare
the two). ``"auto"`` (default) is fused for CPU float32/float64 tensors, else the reference.
Both give the same loss, gradients and stats (to float rounding).
"""

from __future__ import annotations

import torch

from trase.objectives.base import (
    CORRESPONDENCES,
    TAU_NEG,
    TAU_POS,
    Objective,
    PairStats,
    PixelSample,
    norm_regulariser,
    pair_stats,
    register_objective,
    regulariser_features,
)
from trase.objectives.fused import fused_pair_losses

ANCHOR_SIDES = ("column", "row", "either")
NORMALISATIONS = ("anchor_pairs", "selected")
IMPLS = ("auto", "fused", "reference")


def use_fused(impl: str, features: torch.Tensor) -> bool:
    """Whether ``impl`` runs the fused kernels on these features (auto: CPU tensors)."""
    if impl not in IMPLS:
        raise ValueError(f"impl must be one of {IMPLS}, got {impl!r}")
    supported = features.device.type == "cpu" and features.dtype in (torch.float32, torch.float64)
    if impl == "fused" and not supported:
        raise ValueError(f"impl='fused' runs on CPU float32/float64 tensors, got {features.dtype} on {features.device}")
    return impl == "fused" or (impl == "auto" and supported)


def _any_offdiag(m: torch.Tensor) -> torch.Tensor:
    """[V, V] bool (consumed in place) -> [V] column-wise any, ignoring the diagonal."""
    m.fill_diagonal_(False)
    return m.any(dim=0)


def soft_anchors(ps: PairStats, tau_pos: float = TAU_POS, tau_neg: float = TAU_NEG):
    """-> (pos_anchor [V] bool, neg_anchor [V] bool): pixels with at least one imperfect
    positive (``ps.positive``, C_F < tau_pos) or negative (``ps.negative``, C_F > tau_neg)
    partner, diagonal excluded."""
    CF = ps.CF.detach()
    pos = _any_offdiag(ps.positive & (CF < tau_pos))
    neg = _any_offdiag(ps.negative & (CF > tau_neg))
    return pos, neg


def all_anchors(ps: PairStats):
    """-> (pos_anchor, neg_anchor): pixels with any positive / any negative partner ("all")."""
    return _any_offdiag(ps.positive.clone()), _any_offdiag(ps.negative.clone())


def anchor_pair_count(anchor: torch.Tensor, side: str = "column") -> int:
    """Number of upper-triangle pairs (i < j) whose ``side`` member is an anchor, in O(V)."""
    V = anchor.shape[0]
    idx = torch.arange(V, device=anchor.device)
    if side == "column":  # pair (i, j) counted for anchor j: j pairs with i < j
        return int((idx * anchor).sum())
    if side == "row":  # anchor i pairs with V - 1 - i partners j > i
        return int(((V - 1 - idx) * anchor).sum())
    if side == "either":
        k = V - int(anchor.sum())  # pairs with neither member an anchor: C(k, 2)
        return V * (V - 1) // 2 - k * (k - 1) // 2
    raise ValueError(f"anchor side must be one of {ANCHOR_SIDES}, got {side!r}")


def anchor_pairs(anchor: torch.Tensor, upper: torch.Tensor, side: str = "column") -> torch.Tensor:
    """[V] anchor flags -> [V, V] bool upper-triangle pairs whose ``side`` member is an anchor."""
    if side == "column":
        sel = anchor[None, :]
    elif side == "row":
        sel = anchor[:, None]
    elif side == "either":
        sel = anchor[None, :] | anchor[:, None]
    else:
        raise ValueError(f"anchor side must be one of {ANCHOR_SIDES}, got {side!r}")
    return upper & sel


def select_pairs(ps: PairStats, pos_anchor, neg_anchor, side: str = "column"):
    """-> (pos_pairs, neg_pairs, pos_candidates, neg_candidates), all [V, V] bool.

    candidates: upper pairs on an anchor of that kind (the public code's Z); pairs: the
    candidates that are positive (``ps.positive``) resp. negative (``ps.negative``)."""
    pos_cand = anchor_pairs(pos_anchor, ps.upper, side)
    neg_cand = anchor_pairs(neg_anchor, ps.upper, side)
    return pos_cand & ps.positive, neg_cand & ps.negative, pos_cand, neg_cand


def weighted_pair_losses(ps: PairStats, pos_pairs, neg_pairs, z_pos, z_neg):
    """L_pos = -sum(W C_F)/Z_pos over pos_pairs, L_neg = sum(W relu(C_F))/Z_neg over neg_pairs
    (W C and W (1 - C) with the soft correspondence: ``PairStats.pair_weights``).

    W and the selections are constants, so each term is ``ps.pair_sum(coef)`` with one
    constant coefficient matrix (relu folded in as the mask C_F > 0, which is also its exact
    gradient). Z is clamped to >= 1, so empty selections give 0.
    ``weighted_pair_losses_reference`` is the literal element-wise form the tests compare."""
    CF = ps.CF
    zp = max(float(z_pos), 1.0)
    zn = max(float(z_neg), 1.0)
    w_pos, w_neg = ps.pair_weights()
    zero = w_pos.new_zeros(())
    l_pos = -ps.pair_sum(torch.where(pos_pairs, w_pos, zero)) / zp
    l_neg = ps.pair_sum(torch.where(neg_pairs & (CF > 0), w_neg, zero)) / zn
    return l_pos, l_neg


def combine_pair_losses(n_valid: int, features, l_pos, l_neg, n_pos: int, n_neg: int,
                        reg_weight: float = 1.0) -> tuple[torch.Tensor, dict]:
    """L = L_pos + L_neg + reg_weight * regulariser, with the stats every mining rule reports.
    ``n_valid``: pixels in >= 1 sampled mask (an int, or the ``PairStats`` they came from);
    ``features``: what the regulariser averages over (``base.regulariser_features``)."""
    if isinstance(n_valid, PairStats):
        n_valid = int(n_valid.valid.sum())
    reg = norm_regulariser(features)
    loss = l_pos + l_neg + reg_weight * reg
    stats = {
        "loss_pos": float(l_pos.detach()),
        "loss_neg": float(l_neg.detach()),
        "reg": float(reg.detach()),
        "n_pos": n_pos,
        "n_neg": n_neg,
        "n_valid": int(n_valid),
    }
    return loss, stats


def weighted_pair_losses_reference(ps: PairStats, pos_pairs, neg_pairs, z_pos, z_neg):
    """Plain form of ``weighted_pair_losses`` with C_F rebuilt in the autograd graph."""
    CF = ps.fn @ ps.fn.T
    zp = max(float(z_pos), 1.0)
    zn = max(float(z_neg), 1.0)
    w_pos, w_neg = ps.pair_weights()
    l_pos = -(w_pos * CF * pos_pairs).sum() / zp
    l_neg = (w_neg * torch.relu(CF) * neg_pairs).sum() / zn
    return l_pos, l_neg


@register_objective("trase")
class SoftMining(Objective):
    """Soft-mined contrastive loss + feature-norm regulariser (TRASE)."""

    uses_norm_regulariser = True

    def __init__(
        self,
        tau_pos: float = TAU_POS,
        tau_neg: float = TAU_NEG,
        anchor_side: str = "column",
        normalise: str = "anchor_pairs",
        reg_weight: float = 1.0,
        impl: str = "auto",
        correspondence: str = "binary",
    ) -> None:
        super().__init__()
        if impl not in IMPLS:
            raise ValueError(f"impl must be one of {IMPLS}, got {impl!r}")
        if correspondence not in CORRESPONDENCES:
            raise ValueError(f"correspondence must be one of {CORRESPONDENCES}, got {correspondence!r}")
        if anchor_side not in ANCHOR_SIDES:
            raise ValueError(f"anchor_side must be one of {ANCHOR_SIDES}, got {anchor_side!r}")
        if normalise not in NORMALISATIONS:
            raise ValueError(f"normalise must be one of {NORMALISATIONS}, got {normalise!r}")
        self.tau_pos, self.tau_neg = float(tau_pos), float(tau_neg)
        self.anchor_side, self.normalise = anchor_side, normalise
        self.reg_weight = float(reg_weight)
        self.impl = impl
        self.correspondence = correspondence

    def thresholds(self) -> tuple[float, float]:
        """(tau_pos, tau_neg) of the anchor test; (inf, -inf) makes every pixel with a
        positive (negative) partner an anchor ("all" mining)."""
        return self.tau_pos, self.tau_neg

    def anchors(self, ps: PairStats):
        return soft_anchors(ps, *self.thresholds())

    def forward(self, features: torch.Tensor, sample: PixelSample) -> tuple[torch.Tensor, dict]:
        """features [Np, D] rendered at sample.pixels -> (loss, stats)."""
        if not use_fused(self.impl, features):
            return self.forward_reference(features, sample)
        tau_pos, tau_neg = self.thresholds()
        l_pos, l_neg, n_pos, n_neg, n_valid = fused_pair_losses(
            features, sample, tau_pos=tau_pos, tau_neg=tau_neg, side=self.anchor_side,
            normalise=self.normalise, correspondence=self.correspondence)
        return combine_pair_losses(n_valid, regulariser_features(features, sample), l_pos, l_neg, n_pos, n_neg,
                                   self.reg_weight)

    def forward_reference(self, features: torch.Tensor, sample: PixelSample) -> tuple[torch.Tensor, dict]:
        """The dense torch form (readable; the tests compare ``forward`` against it)."""
        ps = pair_stats(features, sample, self.correspondence)
        pos_a, neg_a = self.anchors(ps)
        pos, neg, _, _ = select_pairs(ps, pos_a, neg_a, self.anchor_side)
        n_pos, n_neg = int(torch.count_nonzero(pos)), int(torch.count_nonzero(neg))
        if self.normalise == "anchor_pairs":
            z_pos = anchor_pair_count(pos_a, self.anchor_side)
            z_neg = anchor_pair_count(neg_a, self.anchor_side)
        else:
            z_pos, z_neg = n_pos, n_neg
        l_pos, l_neg = weighted_pair_losses(ps, pos, neg, z_pos, z_neg)
        return combine_pair_losses(ps, regulariser_features(features, sample), l_pos, l_neg, n_pos, n_neg,
                                   self.reg_weight)
