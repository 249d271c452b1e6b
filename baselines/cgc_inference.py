"""CGC's own inference: select gaussians by feature similarity to a clicked query, no clustering.

TRASE clusters the gaussian features and a click picks a cluster; CGC (as run by the TRASE
authors in their dynamic port, yunjinli/contrastive-gaussian-clustering ``render.py``) has no
clustering step. Per click:

    q   = mean of the rendered feature map over a 5 x 5 pixel patch at the click
          (rendered at the click's camera and time)
    sel = { g : cos(f_g, q) >= 0.7 }             f_g: the gaussian's feature
    mask(view) = rendered alpha of the selected gaussians alone >= 0.5

and several clicks take the union of their selections. The paper (Sec. 5, filtering ablation)
notes that CGC "already incorporates a similarity threshold during inference", which is why
TRASE's cluster filter is not applied on top.

Choices:
* The patch is centred on the clicked pixel and clipped to the image (the public code takes
  ``[y : y + 5, x : x + 5]``, i.e. the click is its top-left corner; a centred window is the
  evident intent and is symmetric).
* Cosines are computed in float32 (the public code uses float16).
* A click whose patch has a zero rendered feature (nothing rendered there) selects nothing.
* The gaussian features are those the shared pipeline saves (smoothed over K neighbours, as
  for every method here).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from trase.camera import Camera
from trase.prompts import Click, geometry_at
from trase.render import rasterize

THRESHOLD = 0.7  # cosine similarity to the query (public code)
PATCH = 5  # query patch side in pixels (public code)
NORM_EPS = 1e-12


class CGCInferenceError(ValueError):
    """Bad input to CGC's similarity selection; the message says which argument."""

    user_facing = True


@torch.no_grad()
def render_feature_map(
    gaussians, deformation, features: torch.Tensor, camera: Camera
) -> torch.Tensor:
    """[H, W, D] rendered features (sum_i w_i f_i) of the full scene at camera.time."""
    features = torch.as_tensor(features)
    if features.ndim != 2 or features.shape[0] != gaussians.num_gaussians:
        raise CGCInferenceError(
            f"features must be [N={gaussians.num_gaussians}, D], got {tuple(features.shape)}"
        )
    if features.shape[0] == 0:
        return torch.zeros(camera.height, camera.width, features.shape[1])
    m, q, s, o = geometry_at(gaussians, deformation, camera.time)
    return rasterize(m, q, s, o, camera, features=features.to(m.dtype)).features


def patch_query(feature_map: torch.Tensor, u: float, v: float, patch: int = PATCH) -> torch.Tensor:
    """feature_map [H, W, D], click (u, v) in continuous pixel coordinates -> [D] mean over the
    ``patch x patch`` window centred on pixel (floor(v), floor(u)), clipped to the image."""
    if patch < 1:
        raise CGCInferenceError(f"patch must be >= 1 pixel, got {patch}")
    H, W = feature_map.shape[:2]
    if not (0 <= u < W and 0 <= v < H):
        raise CGCInferenceError(f"click ({u}, {v}) lies outside the {W}x{H} image")
    r, c = int(np.floor(v)), int(np.floor(u))
    lo = patch // 2
    window = feature_map[max(r - lo, 0) : r - lo + patch, max(c - lo, 0) : c - lo + patch]
    return window.reshape(-1, feature_map.shape[2]).mean(dim=0)


def similarity_select(
    features: torch.Tensor, queries: torch.Tensor, threshold: float = THRESHOLD
) -> np.ndarray:
    """features [N, D], queries [Q, D] -> [N] bool: cos(f_g, q) >= threshold for any query.

    Zero features or queries have cosine 0 (never selected for threshold > 0)."""
    f = torch.as_tensor(features, dtype=torch.float32)
    q = torch.as_tensor(queries, dtype=torch.float32).reshape(-1, f.shape[1] if f.ndim == 2 else 0)
    if f.ndim != 2:
        raise CGCInferenceError(f"features must be [N, D], got {tuple(f.shape)}")
    if not -1.0 <= threshold <= 1.0:
        raise CGCInferenceError(f"threshold must be a cosine in [-1, 1], got {threshold}")
    if q.shape[0] == 0 or f.shape[0] == 0:
        return np.zeros(f.shape[0], bool)
    fn = f / f.norm(dim=1, keepdim=True).clamp_min(NORM_EPS)
    qn = q / q.norm(dim=1, keepdim=True).clamp_min(NORM_EPS)
    qn = qn[q.norm(dim=1) > NORM_EPS]  # a query on empty space selects nothing
    if qn.shape[0] == 0:
        return np.zeros(f.shape[0], bool)
    return ((fn @ qn.T) >= threshold).any(dim=1).cpu().numpy()


def select_by_clicks(
    gaussians,
    deformation,
    features: torch.Tensor,
    camera: Camera,
    clicks: Sequence[Click],
    threshold: float = THRESHOLD,
    patch: int = PATCH,
) -> np.ndarray:
    """CGC's click selection -> [N] bool gaussians (union over clicks). Clicks with a time use
    the camera at that time."""
    features = torch.as_tensor(features)
    queries = []
    maps: dict[float, torch.Tensor] = {}
    for click in clicks:
        cam = camera if click.time is None else camera.with_time(click.time)
        if cam.time not in maps:
            maps[cam.time] = render_feature_map(gaussians, deformation, features, cam)
        queries.append(patch_query(maps[cam.time], click.u, click.v, patch))
    if not queries:
        return np.zeros(int(features.shape[0]), bool)
    return similarity_select(features, torch.stack(queries), threshold)
