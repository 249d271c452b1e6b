"""TRASE with hard mining (``trase-hard``): only the individually violating pixel pairs.

The paper's ablation (Sec. 5 and supp. "Soft vs. Hard vs. All Mining") contrasts soft mining
with this rule. Over the valid sampled pixels (those in >= 1 sampled mask, ``pair_stats``):

    P_ij = C_ij = 1  and  C_F,ij < tau_p  and  i < j        (imperfect positive pairs)
    N_ij = C_ij = 0  and  C_F,ij > tau_n  and  i < j        (imperfect negative pairs)

    L_pos = -sum_ij P_ij W_ij C_F,ij        / max(|P|, 1)
    L_neg =  sum_ij N_ij W_ij relu(C_F,ij)  / max(|N|, 1)
    L     = L_pos + L_neg + reg_weight * (1 - mean_p ||F(p)||)^2

Choices:
* W is TRASE's pair weight (``pair_weights``: small-segment pairs weigh up to 10x).
* "Averaged over the selected pairs": each term is divided by its own number of selected
  pairs (Z_pos = |P|, Z_neg = |N|), i.e. a mean over the pairs that term trains. An empty
  selection gives a zero term (Z clamped to 1), never NaN.
* The selection uses C_F detached (a pair's membership in P/N is not differentiated).
* tau_p = 0.75, tau_n = 0.5 and reg_weight = 1, as TRASE.
* ``impl``: "auto" (fused kernels on CPU, ``trase.objectives.fused``), "fused" or
  "reference" (the dense torch form below), as ``SoftMining``; same loss, gradients, stats.
"""

from __future__ import annotations

import torch

from trase.objectives.base import (
    TAU_NEG,
    TAU_POS,
    Objective,
    ObjectiveInputError,
    PairStats,
    PixelSample,
    pair_stats,
    register_objective,
    regulariser_features,
)
from trase.objectives.fused import fused_pair_losses
from trase.objectives.soft import IMPLS, combine_pair_losses, use_fused, weighted_pair_losses


def check_thresholds(tau_pos: float, tau_neg: float) -> None:
    """Cosine thresholds must lie in [-1, 1]."""
    for name, tau in (("tau_pos", tau_pos), ("tau_neg", tau_neg)):
        if not (-1.0 <= float(tau) <= 1.0):
            raise ObjectiveInputError(f"{name} must be a cosine in [-1, 1], got {tau}")


def hard_pairs(
    ps: PairStats, tau_pos: float = TAU_POS, tau_neg: float = TAU_NEG
) -> tuple[torch.Tensor, torch.Tensor]:
    """-> (pos_pairs [V, V] bool, neg_pairs [V, V] bool): the individually violating pairs, i < j."""
    CF = ps.CF.detach()
    pos = ps.C & (CF < tau_pos) & ps.upper
    neg = ~ps.C & (CF > tau_neg) & ps.upper
    return pos, neg


def hard_mining_loss(
    features: torch.Tensor,
    sample: PixelSample,
    tau_pos: float = TAU_POS,
    tau_neg: float = TAU_NEG,
    reg_weight: float = 1.0,
    impl: str = "auto",
) -> tuple[torch.Tensor, dict]:
    """features [Np, D] rendered at sample.pixels -> (scalar loss, stats). See module doc."""
    check_thresholds(tau_pos, tau_neg)
    if use_fused(impl, features):
        l_pos, l_neg, n_pos, n_neg, n_valid = fused_pair_losses(
            features, sample, hard=True, tau_pos=tau_pos, tau_neg=tau_neg)
        return combine_pair_losses(n_valid, regulariser_features(features, sample), l_pos, l_neg, n_pos, n_neg,
                                   reg_weight)
    ps = pair_stats(features, sample)  # checks the feature shape against the sample
    pos, neg = hard_pairs(ps, tau_pos, tau_neg)
    n_pos, n_neg = int(pos.sum()), int(neg.sum())
    l_pos, l_neg = weighted_pair_losses(ps, pos, neg, n_pos, n_neg)
    return combine_pair_losses(ps, regulariser_features(features, sample), l_pos, l_neg, n_pos, n_neg, reg_weight)


@register_objective("trase-hard")
class HardMining(Objective):
    """TRASE's weighted pair loss over only the individually violating pairs (ablation)."""

    uses_norm_regulariser = True

    def __init__(
        self, tau_pos: float = TAU_POS, tau_neg: float = TAU_NEG, reg_weight: float = 1.0,
        impl: str = "auto",
    ) -> None:
        super().__init__()
        check_thresholds(tau_pos, tau_neg)
        if impl not in IMPLS:
            raise ValueError(f"impl must be one of {IMPLS}, got {impl!r}")
        self.impl = impl
        self.tau_pos, self.tau_neg = float(tau_pos), float(tau_neg)
        self.reg_weight = float(reg_weight)

    def forward(self, features: torch.Tensor, sample: PixelSample) -> tuple[torch.Tensor, dict]:
        return hard_mining_loss(features, sample, self.tau_pos, self.tau_neg, self.reg_weight, self.impl)
