"""gsplat backend (CUDA only). UNTESTED HERE: this project's CI and development machines have
no GPU, so this thin adapter has never been run; it is imported lazily and only for CUDA
tensors. Check it against the numba backend (same scene, ``.cpu()``) before trusting it.

Known differences from the CPU backends, all from gsplat's own kernels: alpha is clamped at
0.999 (not 0.99), the screen extent differs slightly, and ties in depth may order differently.
SH colour is evaluated here in torch (same 3DGS formula as the CPU path) and passed to gsplat
together with the features as plain channels; depth uses gsplat's "ED" (alpha-normalised).
"""

from __future__ import annotations

import torch

from trase.render.channels import ALPHA_EPS, channel_parts
from trase.render.types import RenderError, RenderOutput


def rasterize_gsplat(means, quats, scales, opacities, camera, colors, sh_degree, features, background, near):
    try:
        from gsplat import rasterization
    except ImportError as exc:  # pragma: no cover - needs a GPU machine
        raise RenderError(
            "rasterize: backend 'gsplat' needs the gsplat package (pip install gsplat) on a CUDA machine"
        ) from exc
    dev, dt = means.device, means.dtype
    parts = channel_parts(colors, sh_degree, features, means, camera, dt)
    if not parts:
        parts.append(means.new_zeros(means.shape[0], 1))  # gsplat needs at least one channel
    chans = torch.cat(parts, dim=1)
    viewmat = torch.as_tensor(camera.w2c, dtype=dt, device=dev)[None]
    K = torch.as_tensor(camera.K, dtype=dt, device=dev)[None]
    img, alpha, meta = rasterization(
        means, quats, scales, opacities, chans, viewmat, K, camera.width, camera.height,
        near_plane=near, sh_degree=None, render_mode="RGB+ED", packed=False,
    )
    img, alpha = img[0], alpha[0, ..., 0]  # [H, W, C+1], [H, W]
    color = feats = None
    c = 0
    if colors is not None:
        color = img[..., 0:3]
        if background is not None:
            color = color + (1.0 - alpha)[..., None] * background.to(dt).reshape(3)
        c = 3
    if features is not None:
        feats = img[..., c : c + features.shape[1]]
    depth = torch.where(alpha > ALPHA_EPS, img[..., -1], torch.zeros_like(alpha))
    means2d = meta["means2d"][0]  # [N, 2] pixels; retain_grad() gives the screen-space gradient
    radii = meta["radii"][0]  # [N] or [N, 2] (per axis in newer gsplat)
    if radii.ndim == 2:
        radii = radii.max(dim=-1).values
    return RenderOutput(color=color, features=feats, depth=depth, alpha=alpha, means2d=means2d,
                        radii=radii.long())
