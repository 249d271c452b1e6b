"""Shared builders for the baseline-objective tests (imported by name: no package here)."""

from __future__ import annotations

import torch

from trase.objectives.base import PixelSample

NAMES = ("trase-hard", "trase-all", "cgc", "opengaussian")


def make_sample(membership, areas=None, alpha=None, dtype=torch.float64) -> PixelSample:
    """membership: nested list / tensor [Np, M] of 0/1; areas [M] (default 10 each);
    alpha [Np] (default 0.9 everywhere, inside the OpenGaussian silhouette)."""
    m = torch.as_tensor(membership, dtype=torch.bool)
    if m.ndim == 1:
        m = m.reshape(-1, 0) if m.numel() == 0 else m[:, None]
    n, k = m.shape
    area = torch.as_tensor(areas if areas is not None else [10.0] * k, dtype=dtype).reshape(k)
    mean_area = torch.zeros(n, dtype=dtype)
    for i in range(n):
        if m[i].any():
            mean_area[i] = area[m[i]].mean()
    a = torch.full((n,), 0.9, dtype=dtype) if alpha is None else torch.as_tensor(alpha, dtype=dtype)
    return PixelSample(torch.arange(n), m, area, mean_area, alpha=a)


def random_case(seed: int, n: int = 8, m: int = 3, d: int = 4):
    """Random double features [n, d] and a random overlapping membership [n, m]."""
    g = torch.Generator().manual_seed(seed)
    f = torch.randn(n, d, generator=g, dtype=torch.float64)
    member = torch.rand(n, m, generator=g) < 0.45
    areas = (torch.rand(m, generator=g) * 400 + 150).to(torch.float64)  # > 100: kept by cgc
    return f, make_sample(member, areas.tolist())
