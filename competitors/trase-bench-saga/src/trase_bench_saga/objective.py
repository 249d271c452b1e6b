"""SAGA's objective: a scale gate on the feature channels and a scale-conditioned
correspondence loss between sampled pixels.

At a scale s, two pixels correspond where some mask "at that scale" holds both: every mask
whose 3D scale is at least s keeps only the pixels no smaller such mask holds (a pixel belongs
to the smallest mask still as large as s), and the masks smaller than s count as they are. A
scale above every mask's makes all masks count as they are. The rendered features of the
sampled pixels are multiplied by the gate of the scale (one sigmoid per channel of a linear map
of the scale's quantile), normalised, and compared by cosine: corresponding pairs are pulled
to 1, others pushed below 0. Pairs are mined: every pair whose correspondence differs between
the sampled scales, pairs that are wrong at some scale (cosine < 0.75 for a corresponding pair,
> 0.5 for another), and as many of the always-corresponding and never-corresponding pairs as
half the differing ones, drawn at random. Pixels in small masks weigh more (1 to 10, by the
product of the pair's mean covering-mask areas). A term keeps the rendered features' mean norm
near 1.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

POSITIVE_BELOW = 0.75  # a corresponding pair with cosine below this is mined
NEGATIVE_ABOVE = 0.5  # a non-corresponding pair with cosine above this is mined
MAX_PAIR_WEIGHT = 10.0  # pair weights span [1, MAX_PAIR_WEIGHT]


class ScaleGate(torch.nn.Module):
    """quantile of a scale [S] or [S, 1] -> [S, D] channel gates in (0, 1): sigmoid(w s + b)."""

    def __init__(self, dim: int, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.linear = torch.nn.Linear(1, int(dim))
        with torch.no_grad():  # torch's default init for one input: U(-1, 1), drawn from ``generator``
            self.linear.weight.uniform_(-1.0, 1.0, generator=generator)
            self.linear.bias.uniform_(-1.0, 1.0, generator=generator)

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.linear(q.reshape(-1, 1).to(self.linear.weight.dtype)))

    def to_dict(self) -> dict:
        return {"weight": [float(v) for v in self.linear.weight.detach().cpu().reshape(-1)],
                "bias": [float(v) for v in self.linear.bias.detach().cpu().reshape(-1)]}


def gate_from_dict(params: dict, q: float) -> np.ndarray:
    """[D] float64 gates of quantile ``q`` from a saved gate (``ScaleGate.to_dict``)."""
    w, b = np.asarray(params["weight"], np.float64), np.asarray(params["bias"], np.float64)
    return 1.0 / (1.0 + np.exp(-(w * float(q) + b)))


def scale_targets(member: torch.Tensor, index: int) -> torch.Tensor:
    """member [M, P] bool, masks sorted by scale, largest first; ``index``: the mask whose scale is
    sampled (masks 0..index are at least as large), -1: above every mask -> [P, P] float 0/1."""
    member = member.bool()
    M = member.shape[0]
    if index < 0 or M == 0:
        rows = member
    else:
        top = member[: index + 1]  # [k, P]
        k = top.shape[0]
        has = top.any(dim=0)
        last = (k - 1) - torch.argmax(top.flip(0).to(torch.uint8), dim=0)  # smallest such mask per pixel
        own = torch.zeros_like(top)
        cols = torch.nonzero(has).reshape(-1)
        own[last[cols], cols] = True
        rows = torch.cat([own, member[index + 1:]], dim=0)
    r = rows.to(torch.float32)
    return (r.T @ r > 0).to(torch.float32)


def pair_weights(pixel_mean_area: torch.Tensor) -> torch.Tensor:
    """[P] mean area of the masks covering each pixel -> [P, P] weights in [1, MAX_PAIR_WEIGHT]:
    max(a a') / (a_i a_j), at least 1, stretched linearly onto the range."""
    a = pixel_mean_area.to(torch.float64)
    prod = a[:, None] * a[None, :]
    prod = torch.where(prod > 0, prod, torch.full_like(prod, 1e10))
    w = torch.clamp(prod.max() / prod, min=1.0) if prod.numel() else prod
    if w.numel() == 0:
        return w.to(torch.float32)
    lo, hi = w.min(), w.max()
    if hi <= lo:
        return torch.ones_like(w, dtype=torch.float32)
    return ((w - lo) / (hi - lo) * (MAX_PAIR_WEIGHT - 1.0) + 1.0).to(torch.float32)


def mined_pairs(corr: torch.Tensor, targets: torch.Tensor, rand: torch.Tensor,
                positive_below: float = POSITIVE_BELOW, negative_above: float = NEGATIVE_ABOVE):
    """corr, targets [S, P, P], rand [P, P] in [0, 1) -> (positive, negative) [P, P] bool pair
    masks, upper triangle without the diagonal."""
    S, P = targets.shape[0], targets.shape[1]
    votes = targets.sum(dim=0)
    always, never = votes == S, votes == 0
    differ = ~(always | never)
    half = differ.sum().to(torch.float64) / 2.0
    take_always = always & (rand < half / always.sum())
    take_never = never & (rand < half / never.sum())
    with torch.no_grad():
        wrong_pos = ((corr < positive_below) & (targets == 1)).any(dim=0)
        wrong_neg = ((corr > negative_above) & (targets == 0)).any(dim=0)
    upper = torch.ones(P, P, dtype=torch.bool, device=corr.device).triu(diagonal=1)
    return (take_always | wrong_pos | differ) & upper, (take_never | wrong_neg | differ) & upper


def saga_loss(rendered: torch.Tensor, gates: torch.Tensor, targets: torch.Tensor, weights: torch.Tensor,
              rand: torch.Tensor, positive_below: float = POSITIVE_BELOW,
              negative_above: float = NEGATIVE_ABOVE) -> tuple[torch.Tensor, dict]:
    """rendered [P, D] features of the sampled pixels, gates [S, D], targets [S, P, P], weights
    [P, P], rand [P, P] -> (correspondence loss, stats). The norm term is the caller's."""
    f = F.normalize(rendered[None, :, :] * gates[:, None, :], dim=-1)  # [S, P, D]
    corr = f @ f.transpose(1, 2)  # [S, P, P]
    pos, neg = mined_pairs(corr, targets, rand, positive_below, negative_above)
    # the means over [S, pairs] of the public code, as masked sums (no gathers of [S, P, P])
    S = targets.shape[0]
    n_pos, n_neg = pos.sum(), neg.sum()
    wp = (weights * pos)[None]  # [1, P, P]
    wn = (weights * neg)[None]
    pull = -(wp * targets * corr).sum() / (S * n_pos.clamp(min=1))
    push = (wn * (1.0 - targets) * torch.relu(corr)).sum() / (S * n_neg.clamp(min=1))
    with torch.no_grad():
        n_t = targets.sum()
        n_f = targets.numel() - n_t
        c_t = (corr * targets).sum()
        cos_pos = float(c_t / n_t) if n_t > 0 else float("nan")
        cos_neg = float((corr.sum() - c_t) / n_f) if n_f > 0 else float("nan")
    stats = {"pull": float(pull.detach()), "push": float(push.detach()), "cos_pos": cos_pos, "cos_neg": cos_neg,
             "pos_pairs": int(pos.sum()), "neg_pairs": int(neg.sum())}
    return pull + push, stats
