"""What every backend composites per gaussian: colour (RGB or SH evaluated toward the camera),
then features, in that order; one assembly for all backends."""

from __future__ import annotations

import math

import torch

from trase.camera import Camera
from trase.render.sh import sh_to_rgb

ALPHA_EPS = 1e-6  # depth is 0 where accumulated alpha is below this


def gaussian_colors(colors, sh_degree, means, camera: Camera) -> torch.Tensor:
    """[N, 3] RGB as given, or SH [N, K, 3] evaluated toward the camera centre (3DGS)."""
    if colors.ndim == 2:
        return colors
    deg = sh_degree if sh_degree is not None else round(math.sqrt(colors.shape[1])) - 1
    center = torch.as_tensor(camera.center, dtype=means.dtype, device=means.device)
    return sh_to_rgb(deg, colors, means, center)


def channel_parts(colors, sh_degree, features, means, camera: Camera, dtype) -> list[torch.Tensor]:
    """[[N, 3] colour if given, [N, D] features if given], in ``dtype``: the channels a backend
    concatenates (each adds what it needs after them, e.g. depth)."""
    parts = []
    if colors is not None:
        parts.append(gaussian_colors(colors, sh_degree, means, camera).to(dtype))
    if features is not None:
        parts.append(features.to(dtype))
    return parts
