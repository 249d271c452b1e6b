"""The two losses of identity classification (Gaussian Grouping, Ye et al., Sec. 3.2).

* ``identity_loss``: cross-entropy of the classified rendered identity against the pixels'
  track ids, divided by log(C) so that a uniform guess scores 1 (the public code's
  normalisation).
* ``knn_consistency``: the 3D regulariser. For a random sample of gaussians, the KL divergence
  between each one's class distribution and those of its k nearest gaussians in 3D (the point
  itself among them), averaged, divided by the number of classes and weighted.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

KL_EPS = 1e-10  # inside the logarithms, as the public code has it


def identity_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """logits [P, C], target [P] int64 in 0..C-1 -> mean cross-entropy / log(C)."""
    n_classes = logits.shape[1]
    if logits.shape[0] == 0:
        return logits.sum() * 0.0
    return F.cross_entropy(logits, target) / math.log(n_classes)


def knn_indices(points: np.ndarray, query: np.ndarray, k: int) -> np.ndarray:
    """[Q, k] indices of the k nearest ``points`` to each ``query`` row (itself included when
    it is one of the points), nearest first."""
    from scipy.spatial import cKDTree

    k = min(int(k), len(points))
    _, idx = cKDTree(points).query(query, k=k)
    return np.asarray(idx, np.int64).reshape(len(query), k)


def knn_consistency(positions: torch.Tensor, probs: torch.Tensor, k: int = 5, weight: float = 2.0,
                    max_points: int = 300000, sample_size: int = 1000,
                    generator: torch.Generator | None = None) -> torch.Tensor:
    """The 3D regulariser: positions [N, 3] (no gradient), probs [N, C] class probabilities.

    Where N > max_points, a random max_points of the gaussians stand for all of them; then a
    random ``sample_size`` of those are the anchors; each anchor's k nearest (among the kept,
    itself included) give KL(p_anchor || p_neighbour) summed over classes; mean over anchors
    and neighbours, / C, x weight."""
    n, n_classes = probs.shape
    if n == 0 or k < 1 or sample_size < 1:
        return probs.sum() * 0.0
    keep = None
    if n > max_points:
        keep = torch.randperm(n, generator=generator)[:max_points]
        positions, probs = positions[keep.to(positions.device)], probs[keep.to(probs.device)]
        n = max_points
    anchors = torch.randperm(n, generator=generator)[:sample_size]
    pts = positions.detach().cpu().numpy().astype(np.float64)
    nbr = torch.from_numpy(knn_indices(pts, pts[anchors.numpy()], k)).to(probs.device)  # [S, k]
    # index_select, not probs[nbr]: the backward of advanced indexing with repeated indices adds
    # with atomics on several CPU threads, in an order that changes from run to run; index_select's
    # backward (index_add) adds in index order, so a run reproduces its bits
    p = torch.index_select(probs, 0, anchors.to(probs.device)).unsqueeze(1)  # [S, 1, C]
    q = torch.index_select(probs, 0, nbr.reshape(-1)).reshape(*nbr.shape, n_classes)  # [S, k, C]
    kl = (p * (torch.log(p + KL_EPS) - torch.log(q + KL_EPS))).sum(-1).mean()
    return weight * kl / n_classes


__all__ = ["identity_loss", "knn_consistency", "knn_indices"]
