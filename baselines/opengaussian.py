"""OpenGaussian's instance-feature objective (``opengaussian``; Wu et al. 2024, stage 1).

Facts from the public code (OpenGaussian and the TRASE authors' dynamic port
yunjinli/OpenGaussian: ``cohesion_loss``, ``separation_loss``, ``mask_feature_mean``); the code
here is our own. Over the sampled pixels p with rendered features F(p) (not normalised: the
public code normalises the gaussian features, not the rendered ones) and the sampled masks m:

    S     = { p : alpha(p) > 0.7 }                              rendered silhouette
    f_m   = mean_{p in m and S} F(p)                             per-mask mean feature
    intra = mean_m  mean_{p in m} ||F(p) - f_m||                 (all of m's pixels, not just S)
    d_mn  = ||f_m - f_n||^2,   g_mn = 1 / (d_mn + 1)  (m != n), g_mm = 0
    r_mn  = rank of g_mn within row m, ascending (0 .. N-1; the zero diagonal ranks 0)
    w_mn  = 0.1 + 0.9 * r_mn / (N - 1)                           closer masks weigh more
    inter = sum_{m != n} w_mn g_mn / (N (N - 1))
    L     = inter + 0.1 * intra

Choices and differences from the public code:

* Masks may overlap here (SAM "anything" masks); the public code uses one SAM level whose masks
  do not overlap. Both terms are defined per mask, so overlapping masks need no label map.
* A mask with no sampled pixel inside the silhouette has no mean; it is dropped from both terms
  (the public code would give it a zero mean, count clamped to 1). Masks with no sampled pixel
  at all are dropped too. N counts the remaining masks; N < 2 gives inter = 0.
* The ranks are computed on detached g with a stable sort (ties: lower index ranks lower);
  the weights are constants of the step.
* The public schedule's late switch (after step 35000, weights < 0.9 become 0.1) and its mask
  filter (``filter_th`` = 50 px) are not used: feature learning here runs ~10k steps on frozen
  geometry and masks come from the shared sampler.
* ``alpha`` must be supplied in the ``PixelSample`` (the frozen-geometry path has it as the
  sum of compositing weights); without it the objective refuses rather than guessing.
* ||x|| at x = 0 has no derivative; torch's vector_norm back-propagates the subgradient 0
  there (a one-pixel mask is at its own mean), so no NaN arises.
"""

from __future__ import annotations

import torch

from trase.objectives.base import (
    Objective,
    ObjectiveInputError,
    PixelSample,
    check_features,
    register_objective,
)

ALPHA_THRESHOLD = 0.7  # silhouette: rendered alpha above this (public code)
INTRA_WEIGHT = 0.1  # L = inter + 0.1 * intra (public ``loss_weight``)
W_MIN = 0.1  # rank weights span [0.1, 1]


def silhouette_means(
    features: torch.Tensor, membership: torch.Tensor, silhouette: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """features [Np, D], membership [Np, M] bool, silhouette [Np] bool ->
    (means [M', D] over mask-and-silhouette pixels, kept [M] bool: masks with such pixels)."""
    inside = (membership & silhouette[:, None]).to(features.dtype)  # [Np, M]
    count = inside.sum(dim=0)  # [M]
    kept = count > 0
    means = (inside[:, kept].T @ features) / count[kept][:, None]  # [M', D]
    return means, kept


def cohesion(features: torch.Tensor, membership: torch.Tensor, means: torch.Tensor) -> torch.Tensor:
    """Mean over masks of the mean distance of a mask's pixels to its mean.
    features [Np, D], membership [Np, M'] bool, means [M', D] -> scalar (0 if M' = 0)."""
    if means.shape[0] == 0:
        return features.sum() * 0.0
    member = membership.to(features.dtype)  # [Np, M']
    dist = torch.linalg.vector_norm(features[:, None, :] - means[None, :, :], dim=2)  # [Np, M']
    per_mask = (dist * member).sum(dim=0) / member.sum(dim=0).clamp_min(1.0)  # [M']
    return per_mask.mean()


def rank_weights(g: torch.Tensor) -> torch.Tensor:
    """g [N, N] (zero diagonal) -> weights 0.1 + 0.9 * rank/(N-1), rank ascending per row."""
    n = g.shape[0]
    order = torch.argsort(g.detach(), dim=1, stable=True)
    rank = torch.argsort(order, dim=1, stable=True).to(g.dtype)  # [N, N] in 0..N-1
    return W_MIN + (1.0 - W_MIN) * rank / (n - 1)


def separation(means: torch.Tensor) -> torch.Tensor:
    """Rank-weighted mean inverse squared distance between mask means [N, D] -> scalar."""
    n = means.shape[0]
    if n < 2:
        return means.sum() * 0.0
    diff = means[:, None, :] - means[None, :, :]  # [N, N, D]
    g = 1.0 / ((diff * diff).sum(dim=2) + 1.0)  # [N, N]
    off = ~torch.eye(n, dtype=torch.bool, device=means.device)
    g = g * off  # zero diagonal (masked product keeps the graph)
    return (rank_weights(g) * g).sum() / (n * (n - 1))


def opengaussian_loss(
    features: torch.Tensor,
    sample: PixelSample,
    alpha_threshold: float = ALPHA_THRESHOLD,
    intra_weight: float = INTRA_WEIGHT,
) -> tuple[torch.Tensor, dict]:
    """features [Np, D] rendered at sample.pixels (sample.alpha required) -> (loss, stats)."""
    check_features(features, sample)
    if sample.alpha is None:
        raise ObjectiveInputError(
            "opengaussian needs the rendered alpha of the sampled pixels (PixelSample.alpha), got "
            "None: the training loop must render it for objectives with needs_alpha = True"
        )
    silhouette = sample.alpha.to(features.device) > alpha_threshold  # [Np]
    means, kept = silhouette_means(features, sample.membership, silhouette)
    intra = cohesion(features, sample.membership[:, kept], means)
    inter = separation(means)
    loss = inter + intra_weight * intra
    stats = {
        "loss_inter": float(inter.detach()),
        "loss_intra": float(intra.detach()),
        "n_masks": int(kept.sum()),
        "silhouette_fraction": float(silhouette.float().mean()) if silhouette.numel() else 0.0,
    }
    return loss, stats


@register_objective("opengaussian")
class OpenGaussianObjective(Objective):
    """OpenGaussian stage 1: inter-mask separation + 0.1 * intra-mask cohesion."""

    needs_alpha = True  # the training loop must fill PixelSample.alpha (rendered silhouette)

    def __init__(
        self, alpha_threshold: float = ALPHA_THRESHOLD, intra_weight: float = INTRA_WEIGHT
    ):
        super().__init__()
        if not 0.0 <= alpha_threshold < 1.0:
            raise ObjectiveInputError(f"alpha_threshold must be in [0, 1), got {alpha_threshold}")
        self.alpha_threshold, self.intra_weight = float(alpha_threshold), float(intra_weight)

    def forward(self, features: torch.Tensor, sample: PixelSample) -> tuple[torch.Tensor, dict]:
        return opengaussian_loss(features, sample, self.alpha_threshold, self.intra_weight)
