"""Gaussians the training views barely see, and features for them from their seen neighbours.

Why: a feature is learned only where a gaussian is drawn into training pixels. With few or
small training views (the tiny synthetic scenes: 3-6 views of 64x48 px) most gaussians are
drawn into almost none; their features stay near their random start, and the clustering mixes
them into every cluster. A gaussian's nearest seen neighbours in 3D are the best evidence of
what it belongs to, so before clustering its feature is replaced by theirs (the mean of their
normalised features, at its own norm). Measured in docs/notes/corrective-clicks.md ("Features of the
barely seen gaussians from their seen neighbours").
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from scipy.spatial import cKDTree

from trase.camera import Camera
from trase.prompts import geometry_at
from trase.render import pixel_weights


@torch.no_grad()
def training_weights(gaussians, deformation, cameras: Sequence[Camera]) -> np.ndarray:
    """[N] float64: each gaussian's compositing weights (alpha * T) summed over every pixel of
    every camera, at each camera's time: how much of the training images it draws."""
    total = np.zeros(gaussians.num_gaussians, np.float64)
    for cam in cameras:
        m, q, s, o = geometry_at(gaussians, deformation, cam.time)
        pw = pixel_weights(m, q, s, o, cam)
        total += np.bincount(pw.indices.cpu().numpy(), weights=pw.weights.cpu().numpy().astype(np.float64),
                             minlength=total.size)
    return total


def neighbours_features(features: np.ndarray, means: np.ndarray, seen: np.ndarray, k: int) -> np.ndarray:
    """features [N, D] with each unseen row (``seen`` [N] bool False) replaced by the mean of the
    normalised features of its ``k`` nearest seen gaussians (``means`` [N, 3]), scaled to the
    row's own norm. Unchanged where fewer than ``k`` gaussians are seen or none is unseen."""
    features = np.asarray(features, np.float32)
    seen = np.asarray(seen, bool)
    if k < 1 or seen.sum() < k or seen.all():
        return features
    norms = np.linalg.norm(features, axis=1, keepdims=True)  # [N, 1]
    unit = features / np.maximum(norms, 1e-12)
    _, idx = cKDTree(np.asarray(means, np.float64)[seen]).query(np.asarray(means, np.float64)[~seen], k=k)
    idx = idx.reshape(-1, k)  # [U, k] (query returns [U] for k = 1)
    mean = unit[seen][idx].mean(axis=1)  # [U, D]
    out = features.copy()
    out[~seen] = mean * np.maximum(norms[~seen], 1e-6)
    return out


__all__ = ["neighbours_features", "training_weights"]
