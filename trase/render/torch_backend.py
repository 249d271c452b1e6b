"""Reference compositing in plain torch (autograd does the backward). Readable, not fast.

Per tile: the gaussians whose tile rectangle covers the tile, sorted front to back by camera
z (stable, ties by index: the same order the numba backend uses), are evaluated at the
tile's pixel centres all at once. 3DGS's sequential rules become masks:
  * skip a gaussian at a pixel when power > 0 or alpha < 1/255 (alpha set to 0),
  * stop before the first gaussian whose inclusion would take T below 1e-4: with the
    inclusive product C_k = prod_{j<=k} (1 - alpha_j), gaussian k is used iff C_k >= 1e-4
    (C is non-increasing, so this is exactly a prefix, as in the sequential loop).
"""

from __future__ import annotations

import torch

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4


def composite_torch(
    means2d: torch.Tensor,  # [N, 2]
    conics: torch.Tensor,  # [N, 3]
    opacities: torch.Tensor,  # [N]
    channels: torch.Tensor,  # [N, C]
    depths: torch.Tensor,  # [N] sort key
    rects: torch.Tensor,  # [N, 4] int64 (x0, x1, y0, y1) tile ranges
    width: int,
    height: int,
    tile_size: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """-> (out [H, W, C] = sum_i w_i channels_i, alpha [H, W] = sum_i w_i)."""
    dev, dt = channels.device, channels.dtype
    C = channels.shape[1]
    gx = (width + tile_size - 1) // tile_size
    gy = (height + tile_size - 1) // tile_size
    order = torch.sort(depths.detach(), stable=True).indices  # front to back
    r = rects[order]
    idx_parts, out_parts, alpha_parts = [], [], []
    for ty in range(gy):
        for tx in range(gx):
            hit = (r[:, 0] <= tx) & (tx < r[:, 1]) & (r[:, 2] <= ty) & (ty < r[:, 3])
            ids = order[hit]  # [K] depth-sorted gaussians of this tile
            if ids.numel() == 0:
                continue
            cols = torch.arange(tx * tile_size, min((tx + 1) * tile_size, width), device=dev)
            rows = torch.arange(ty * tile_size, min((ty + 1) * tile_size, height), device=dev)
            yy, xx = torch.meshgrid(rows, cols, indexing="ij")
            pix = (yy * width + xx).reshape(-1)  # [P]
            centres = torch.stack([xx.reshape(-1), yy.reshape(-1)], dim=1).to(dt) + 0.5  # [P, 2]
            d = centres[:, None, :] - means2d[ids][None]  # [P, K, 2]
            con = conics[ids]
            power = (
                -0.5 * (con[:, 0] * d[..., 0] ** 2 + con[:, 2] * d[..., 1] ** 2)
                - con[:, 1] * d[..., 0] * d[..., 1]
            )  # [P, K]
            alpha = (opacities[ids] * torch.exp(power.clamp_max(0.0))).clamp_max(ALPHA_MAX)
            keep = (power <= 0) & (alpha >= ALPHA_MIN)
            alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
            one_minus = 1.0 - alpha
            incl = torch.cumprod(one_minus, dim=1)  # C_k
            used = keep & (incl.detach() >= T_MIN)
            T = torch.cat([torch.ones_like(incl[:, :1]), incl[:, :-1]], dim=1)  # T_k
            w = torch.where(used, alpha * T, torch.zeros_like(alpha))  # [P, K]
            idx_parts.append(pix)
            out_parts.append(w @ channels[ids])
            alpha_parts.append(w.sum(1))
    out = channels.new_zeros(height * width, C)
    alpha = channels.new_zeros(height * width)
    if idx_parts:
        idx = torch.cat(idx_parts)
        out = out.index_copy(0, idx, torch.cat(out_parts))
        alpha = alpha.index_copy(0, idx, torch.cat(alpha_parts))
    else:  # nothing visible: keep the outputs attached to the graph (zero gradients, not an error)
        zero = 0.0 * (channels.sum() + opacities.sum() + means2d.sum() + conics.sum())
        out, alpha = out + zero, alpha + zero
    return out.reshape(height, width, C), alpha.reshape(height, width)
