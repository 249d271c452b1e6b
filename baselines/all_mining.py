"""TRASE with all mining (``trase-all``): every pixel with a positive (negative) pair is an anchor.

The paper's ablation (Sec. 5 and supp. "Soft vs. Hard vs. All Mining") contrasts soft mining
with this rule. It is TRASE's loss with the anchor test replaced; everything else is shared
with ``trase.objectives.soft`` (same pair selection, weights, normalisation, regulariser):

    pos_anchor(a) = exists k != a : C_ak = 1        neg_anchor(a) = exists k != a : C_ak = 0
    P_ij = pos_anchor(j) and C_ij = 1 and i < j     N_ij = neg_anchor(j) and C_ij = 0 and i < j
    L_pos = -sum P W C_F / Z_pos,   L_neg = sum N W relu(C_F) / Z_neg
    L     = L_pos + L_neg + reg_weight * (1 - mean_p ||F(p)||)^2

Choices (inherited from ``SoftMining``, see its module doc for the alternatives):
* anchor side "column" (public code): the pair's j member must be the anchor. With "all"
  anchors every positive pair has both members positive anchors, so the side only matters at
  the edge: P is exactly all positive pairs i < j and N all negative pairs i < j.
* Z ("anchor_pairs", public code) = number of upper-triangle pairs whose anchor side is an
  anchor of that kind, positive and negative pairs alike; clamped to >= 1.
* Only valid pixels (in >= 1 sampled mask) take part; the diagonal never makes an anchor.
"""

from __future__ import annotations

import math

import torch

from trase.objectives.base import PixelSample, register_objective
from trase.objectives.soft import SoftMining, all_anchors


@register_objective("trase-all")
class AllMining(SoftMining):
    """TRASE's weighted pair loss over all positive and all negative pairs (ablation).

    ``tau_pos``/``tau_neg`` are accepted for a uniform signature but select nothing: the
    "all" rule has no threshold."""

    def thresholds(self) -> tuple[float, float]:
        # every C = 1 pair has C_F < inf and every C = 0 pair C_F > -inf: the fused kernels'
        # soft anchor test with these thresholds is exactly the "all" rule
        return math.inf, -math.inf

    def anchors(self, ps):
        return all_anchors(ps)


def all_mining_loss(
    features: torch.Tensor,
    sample: PixelSample,
    anchor_side: str = "column",
    normalise: str = "anchor_pairs",
    reg_weight: float = 1.0,
    impl: str = "auto",
) -> tuple[torch.Tensor, dict]:
    """features [Np, D] rendered at sample.pixels -> (scalar loss, stats). See module doc."""
    return AllMining(anchor_side=anchor_side, normalise=normalise, reg_weight=reg_weight, impl=impl)(
        features, sample
    )
