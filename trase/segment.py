"""Segmentation output: the selected gaussians rendered alone at a view and time; the pixels
with accumulated alpha >= 0.5 are the predicted mask (as the paper's "Render Object").

Selection = gaussians whose cluster was chosen by a prompt AND that pass the similarity
filter (``keep``; the paper's post-processing). Several clusters merge into one mask.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import torch

from trase.camera import Camera
from trase.prompts import geometry_at
from trase.render import rasterize

ALPHA_THRESHOLD = 0.5


def select_gaussians(labels: np.ndarray, clusters: Iterable[int], keep: np.ndarray | None = None) -> np.ndarray:
    """[N] bool: gaussians in any of ``clusters`` (and in ``keep`` when given)."""
    labels = np.asarray(labels, dtype=np.int64)
    chosen = [int(c) for c in clusters if int(c) >= 0]
    sel = np.isin(labels, np.asarray(chosen, dtype=np.int64)) if chosen else np.zeros(labels.shape, bool)
    if keep is not None:
        sel &= np.asarray(keep, dtype=bool)
    return sel


@torch.no_grad()
def render_alpha(gaussians, deformation, selected: np.ndarray, camera: Camera) -> np.ndarray:
    """[H, W] float32 alpha of the selected gaussians alone at camera.time."""
    sel = torch.as_tensor(np.asarray(selected, dtype=bool))
    if not bool(sel.any()):
        return np.zeros((camera.height, camera.width), np.float32)
    m, q, s, o = geometry_at(gaussians, deformation, camera.time)
    m, q, s, o = m[sel], q[sel], s[sel], o[sel]
    out = rasterize(m, q, s, o, camera, features=torch.zeros(m.shape[0], 1, dtype=m.dtype))
    return out.alpha.cpu().numpy().astype(np.float32)


def render_masks(gaussians, deformation, selected: np.ndarray, cameras: Sequence[Camera],
                 threshold: float = ALPHA_THRESHOLD) -> list[np.ndarray]:
    """Predicted masks (bool [H, W]) at every camera (view + time)."""
    return [render_alpha(gaussians, deformation, selected, cam) >= threshold for cam in cameras]
