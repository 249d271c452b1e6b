"""Small random scenes for the rasterizer tests."""

from __future__ import annotations

import torch

from trase.camera import Camera, intrinsics, look_at


def camera(width=40, height=32, cx=None, cy=None, f=40.0, eye=(0.0, -3.0, 0.3)) -> Camera:
    cx = width / 2 if cx is None else cx
    cy = height / 2 if cy is None else cy
    return Camera(K=intrinsics(f, f, cx, cy), w2c=look_at(eye, [0.0, 0.0, 0.0]), width=width, height=height)


def scene(n=200, d=5, sh_degree=None, seed=0, dtype=torch.float32, spread=0.6, log_scale=-2.5):
    """-> dict of leaf tensors (requires_grad) for rasterize(**scene, camera=...)."""
    g = torch.Generator().manual_seed(seed)
    out = {
        "means": torch.randn(n, 3, generator=g) * spread,
        "quats": torch.randn(n, 4, generator=g),
        "scales": torch.exp(torch.randn(n, 3, generator=g) * 0.4 + log_scale),
        "opacities": torch.rand(n, generator=g) * 0.9 + 0.05,
    }
    if sh_degree is None:
        out["colors"] = torch.rand(n, 3, generator=g)
    else:
        out["colors"] = torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g) * 0.3
        out["sh_degree"] = sh_degree
    if d:
        out["features"] = torch.randn(n, d, generator=g)
    return {k: (v.to(dtype).requires_grad_(True) if torch.is_tensor(v) else v) for k, v in out.items()}


def loss_of(out, seed=1) -> torch.Tensor:
    """A random linear functional of every output, so every gradient path is exercised."""
    g = torch.Generator().manual_seed(seed)
    total = 0.0
    for t in (out.color, out.features, out.depth, out.alpha):
        if t is not None:
            total = total + (t * torch.rand(t.shape, generator=g, dtype=t.dtype)).sum()
    return total


def grads(sc: dict) -> dict:
    return {k: v.grad.clone() for k, v in sc.items() if torch.is_tensor(v) and v.grad is not None}
