"""3DGS's adaptive density control: the screen-space gradient statistic (two ways of getting
it, see ``ReconstructionConfig.densify_statistic``), the scene extent its thresholds scale
with, and one densify-and-prune step."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import torch

from trase.camera import Camera
from trase.gaussians import GaussianModel
from trase.reconstruction_config import ReconstructionConfig


def scene_extent(cameras: Iterable[Camera]) -> float:
    """3DGS's scene radius: 1.1 x the largest camera-centre distance from their mean."""
    centers = np.stack([c.center for c in cameras])
    diag = float(np.linalg.norm(centers - centers.mean(0), axis=1).max())
    return max(diag * 1.1, 1e-6) if diag > 0 else 1.0


def screen_grad_norm(grad_means2d: torch.Tensor, camera: Camera) -> torch.Tensor:
    """|dL/d(mean2D)| in NDC units [N] (3DGS's densification statistic) from the gradient of
    the rendered pixel positions [N, 2]: NDC spans W / 2 pixels per unit in x, H / 2 in y."""
    g = grad_means2d.detach().double()
    n = torch.hypot(g[:, 0] * (0.5 * camera.width), g[:, 1] * (0.5 * camera.height))
    return torch.where(torch.isfinite(n), n, torch.zeros_like(n)).float()


def lstsq_screen_grad_norm(grad_means: torch.Tensor, means: torch.Tensor, camera: Camera) -> torch.Tensor:
    """|dL/d(mean2D)| in NDC units [N] from dL/d(mean3D) [N, 3], by least squares through the
    projection Jacobian J = [[a, 0, -a u], [0, b, -b v]] (a = fx/z, b = fy/z, u = x/z, v = y/z):
    g2 = (J J^T)^-1 J g3, in closed form (det = a^2 b^2 (1 + u^2 + v^2) never vanishes).
    Gaussians at or behind the camera plane get 0."""
    R = torch.as_tensor(camera.w2c[:3, :3], dtype=torch.float64, device=means.device)
    t = torch.as_tensor(camera.w2c[:3, 3], dtype=torch.float64, device=means.device)
    p = means.detach().double() @ R.T + t
    g = grad_means.double() @ R.T  # camera-space gradient
    z = p[:, 2]
    front = z > 1e-6
    zs = torch.where(front, z, torch.ones_like(z))
    u, v = p[:, 0] / zs, p[:, 1] / zs
    a, b = camera.fx / zs, camera.fy / zs
    gp = g[:, 0] - u * g[:, 2]  # (J g)_0 / a
    gq = g[:, 1] - v * g[:, 2]  # (J g)_1 / b
    den = 1.0 + u * u + v * v
    gu = ((1 + v * v) * gp - u * v * gq) / (a * den)  # pixels
    gv = ((1 + u * u) * gq - u * v * gp) / (b * den)
    n = torch.hypot(gu * (0.5 * camera.width), gv * (0.5 * camera.height))
    return torch.where(front & torch.isfinite(n), n, torch.zeros_like(n)).float()


@torch.no_grad()
def densify_and_prune(g: GaussianModel, opt, cfg: ReconstructionConfig, grad_accum, denom,
                       extent: float, prune_large: bool, gen: torch.Generator) -> None:
    """3DGS densify_and_prune: clone small / split large high-gradient gaussians, then drop
    transparent ones and, after the first opacity reset, ones larger than 0.1 x the scene
    extent. (3DGS also tests a screen-size limit, but its radii statistic has just been reset
    to zero by the densification, so that test never fires; it is left out here.)"""
    grads = torch.where(denom > 0, grad_accum / denom.clamp_min(1), torch.zeros_like(grad_accum))
    big = g.scales.max(dim=1).values > cfg.percent_dense * extent
    cand = grads >= cfg.densify_grad_threshold
    if cfg.max_gaussians > 0:
        # each clone adds one, each split adds one net (2 new, 1 removed)
        room = max(cfg.max_gaussians - g.num_gaussians, 0)
        if int(cand.sum()) > room:
            order = torch.argsort(torch.where(cand, grads, torch.full_like(grads, -1.0)), descending=True)
            keep = torch.zeros_like(cand)
            keep[order[:room]] = True
            cand = cand & keep
    clone = cand & ~big
    split = cand & big
    n0 = g.num_gaussians
    g.clone_gaussians(clone, opt)
    split = torch.cat([split, torch.zeros(g.num_gaussians - n0, dtype=torch.bool, device=split.device)])
    g.split_gaussians(split, opt, n=2, generator=gen)
    prune = g.opacities < cfg.min_opacity
    if prune_large:
        prune |= g.scales.max(dim=1).values > 0.1 * extent
    if bool(prune.all()):
        prune[torch.argmax(g.opacities)] = False  # never delete every gaussian
    g.prune(~prune, opt)
