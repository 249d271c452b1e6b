"""The oracle: the clusters a perfect click would choose, from the ground truth.

The clusters whose visible rendered pixels (cluster weight >= 0.5 in the
  full render) lie mostly (> ``min_inside``) inside the ground truth over all test frames:
  what a perfect click would usually reach, reported separately, never as the score. Not a strict
  bound: a click may take a cluster less than half inside the truth that still covers the object
  better (trase-hard on the Neu3D-format scene: clicks 0.794, this oracle 0.553).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from trase.camera import Camera
from trase.prompts import geometry_at
from trase.render import rasterize


@torch.no_grad()
def cluster_visibility(gaussians, deformation, camera: Camera, labels: np.ndarray, n_clusters: int) -> np.ndarray:
    """[H, W, C] rendered weight of each cluster in the full scene (occlusion-aware)."""
    m, q, s, o = geometry_at(gaussians, deformation, camera.time)
    onehot = torch.nn.functional.one_hot(torch.as_tensor(labels, dtype=torch.long), n_clusters).to(m.dtype)
    return rasterize(m, q, s, o, camera, features=onehot).features.cpu().numpy()


def oracle_clusters(gaussians, deformation, cameras: Sequence[Camera], gts: Sequence[np.ndarray],
                    labels: np.ndarray, min_inside: float = 0.5) -> list[int]:
    """Clusters whose visible pixels (weight >= 0.5) are > min_inside inside the ground truth,
    pooled over the given frames."""
    labels = np.asarray(labels, dtype=np.int64)
    if labels.size == 0:
        return []
    C = int(labels.max()) + 1
    inside = np.zeros(C)
    total = np.zeros(C)
    for cam, gt in zip(cameras, gts):
        vis = cluster_visibility(gaussians, deformation, cam, labels, C) >= 0.5  # [H, W, C]
        g = np.asarray(gt, bool)[..., None]
        inside += (vis & g).sum(axis=(0, 1))
        total += vis.sum(axis=(0, 1))
    frac = np.divide(inside, total, out=np.zeros(C), where=total > 0)
    return [int(c) for c in range(C) if total[c] > 0 and frac[c] > min_inside]
