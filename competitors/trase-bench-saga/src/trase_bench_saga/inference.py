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
    from trase.prompts import geometry_at
    from trase.render import pixel_weights

    W, H = camera.width, camera.height
    if not (0 <= u < W and 0 <= v < H) or gaussians.num_gaussians == 0:
        return None
    col, row = int(np.floor(u)), int(np.floor(v))
    r = max(int(radius), 0)
    rows = np.arange(max(row - r, 0), min(row + r, H - 1) + 1)
    cols = np.arange(max(col - r, 0), min(col + r, W - 1) + 1)
    window = (rows[:, None] * W + cols[None, :]).reshape(-1)
    centre = int(np.flatnonzero(window == row * W + col)[0])
    m, q, s, o = geometry_at(gaussians, deformation, camera.time)
    pw = pixel_weights(m, q, s, o, camera, torch.from_numpy(window))
    indptr = pw.indptr.cpu().numpy()
    w = pw.weights.cpu().numpy().astype(np.float64)
    if w[indptr[centre]:indptr[centre + 1]].sum() < min_alpha:
        return None
    idx = pw.indices.cpu().numpy()
    return (w[:, None] * np.asarray(features, np.float64)[idx]).sum(axis=0)
