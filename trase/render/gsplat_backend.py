"""gsplat backend (CUDA only), imported lazily and only for CUDA tensors. Checked on a GPU
(tests/trase/render/test_cuda_backends.py: gsplat 1.5.3 on an H200 against the torch backend
on CUDA, outputs to ~1e-6 and every gradient), and on the CPU against a stand-in for gsplat
built on the torch reference (tests/trase/render/test_gsplat_adapter.py: conventions, the
screen-space gradient).

Known differences from the CPU backends, all from gsplat's own kernels: alpha is clamped at
0.999 (not 0.99), the screen extent differs slightly, and ties in depth may order differently.
A colour-only render of SH coefficients (every reconstruction step) hands the coefficients to
gsplat, whose fused kernel evaluates them with 3DGS's constants and clamp: in torch the same
formula is ~80 small operations forward and twice that backward, which at a few thousand
gaussians cost more than the render (a step is bound by launches there). With features beside
the colour, SH is evaluated in torch (same formula) and passed with the features as plain
channels. Depth uses gsplat's "ED" (alpha-normalised).
"""

from __future__ import annotations

import math

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
    gsplat_sh = colors is not None and colors.ndim == 3 and features is None
    if gsplat_sh:
        chans = colors.to(dt)  # [N, K, 3] SH coefficients, evaluated by gsplat
        degree = sh_degree if sh_degree is not None else round(math.sqrt(colors.shape[1])) - 1
    else:
        parts = channel_parts(colors, sh_degree, features, means, camera, dt)
        if not parts:
            parts.append(means.new_zeros(means.shape[0], 1))  # gsplat needs at least one channel
        chans = torch.cat(parts, dim=1)  # [N, C]
        degree = None
    viewmat = torch.as_tensor(camera.w2c, dtype=dt, device=dev)[None]
    K = torch.as_tensor(camera.K, dtype=dt, device=dev)[None]
    img, alpha, meta = rasterization(
        means, quats, scales, opacities, chans, viewmat, K, camera.width, camera.height,
        near_plane=near, sh_degree=degree, render_mode="RGB+ED", packed=False,
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
    radii = meta["radii"][0]  # [N] or [N, 2] (per axis in newer gsplat)
    if radii.ndim == 2:
        radii = radii.max(dim=-1).values
    return RenderOutput(color=color, features=feats, depth=depth, alpha=alpha,
                        means2d=_screen_positions(meta["means2d"]), radii=radii.long())


def _screen_positions(means2d: torch.Tensor) -> torch.Tensor:
    """gsplat's [1, N, 2] pixel centres -> [N, 2] whose ``.grad`` after backward is the
    screen-space gradient (RenderOutput's contract). A slice taken after the render is not in
    the graph the image came from, so its .grad would stay None (and 3DGS's densification would
    never fire): the gradient of gsplat's own tensor is handed over by a hook."""
    screen = means2d.detach()[0].requires_grad_(means2d.requires_grad)
    if means2d.requires_grad:
        def hand_over(grad: torch.Tensor) -> None:
            g = grad[0].detach()
            screen.grad = g if screen.grad is None else screen.grad + g

        means2d.register_hook(hand_over)
    return screen
