"""Segmentation output: the selected gaussians rendered alone at a view and time; the pixels
with accumulated alpha >= 0.5 are the predicted mask (as the paper's "Render Object").

Rules (``render_masks(rule=...)``):
* ``alone`` (the paper's, the default): alpha of the selected gaussians rendered without the
  rest of the scene. Parts of the object hidden behind other objects are predicted too.
* ``visible``: the selected gaussians' share of the *full* scene's compositing weights,
  sum_{i selected} alpha_i T_i >= threshold: the object where it is seen, which is what
  ground-truth masks of a view mark (measured on the synthetic scenes with ground-truth
  geometry: occluders' pixels are most of the remaining error of ``alone``).

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
RULES = ("alone", "visible")


class SegmentError(ValueError):
    user_facing = True


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


@torch.no_grad()
def render_visible(gaussians, deformation, selected: np.ndarray, camera: Camera) -> np.ndarray:
    """[H, W] float32 sum of the selected gaussians' compositing weights alpha_i T_i in the
    full scene at camera.time (0 where other gaussians hide them)."""
    sel = np.asarray(selected, dtype=bool)
    if gaussians.num_gaussians == 0 or not sel.any():
        return np.zeros((camera.height, camera.width), np.float32)
    m, q, s, o = geometry_at(gaussians, deformation, camera.time)
    out = rasterize(m, q, s, o, camera, features=torch.as_tensor(sel, dtype=m.dtype)[:, None])
    return out.features[..., 0].cpu().numpy().astype(np.float32)


def render_masks(gaussians, deformation, selected: np.ndarray, cameras: Sequence[Camera],
                 threshold: float = ALPHA_THRESHOLD, rule: str = "alone") -> list[np.ndarray]:
    """Predicted masks (bool [H, W]) at every camera (view + time) by ``rule`` (see RULES)."""
    if rule == "alone":
        render = render_alpha
    elif rule == "visible":
        render = render_visible
    else:
        raise SegmentError(f"unknown segmentation rule {rule!r}; choose one of {', '.join(RULES)}")
    return [render(gaussians, deformation, selected, cam) >= threshold for cam in cameras]
