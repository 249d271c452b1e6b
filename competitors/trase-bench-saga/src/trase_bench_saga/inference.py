"""SAGA's click inference: the feature rendered under a click, gated at the chosen scale, is the
query; every gaussian whose gated feature has cosine above the threshold with it is selected
(the union over the clicks). Gated features: the unit feature times the scale's gates, unit
again (the public GUI's form)."""

from __future__ import annotations

import numpy as np
import torch

NORM_EPS = 1e-12


def unit(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, np.float64)
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    return x / np.maximum(n, NORM_EPS)


def gated(features: np.ndarray, gates: np.ndarray) -> np.ndarray:
    """[N, D] features, [D] gates -> [N, D] unit(unit(f) * gates)."""
    return unit(unit(features) * np.asarray(gates, np.float64)[None, :])


def select_by_query(features: np.ndarray, gates: np.ndarray, queries: list[np.ndarray], threshold: float) -> np.ndarray:
    """[N] bool: gaussians whose gated feature has cosine > ``threshold`` with any of ``queries``
    (each a rendered feature [D], gated here)."""
    g = gated(features, gates)
    sel = np.zeros(g.shape[0], bool)
    for q in queries:
        qg = gated(np.asarray(q, np.float64)[None, :], gates)[0]
        if np.linalg.norm(qg) > 0:
            sel |= g @ qg > float(threshold)
    return sel


@torch.no_grad()
def rendered_feature(gaussians, deformation, camera, u: float, v: float, features: np.ndarray,
                     min_alpha: float = 0.5, radius: int = 0) -> np.ndarray | None:
    """The feature rendered at the click (the compositing-weighted sum of the gaussians'
    features over the (2 r + 1)^2 pixels around it); None off the image, on no gaussians, or
    where the clicked pixel's alpha is below ``min_alpha``."""
    from trase.prompts import window_weights

    found = window_weights(gaussians, deformation, camera, u, v, min_alpha, max(int(radius), 0))
    if found is None:
        return None
    idx, w = found
    return (w[:, None] * np.asarray(features, np.float64)[idx]).sum(axis=0)
