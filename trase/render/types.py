"""Result types and the error class of the rasterizer."""

from __future__ import annotations

import dataclasses

import torch


class RenderError(ValueError):
    """Invalid input to the rasterizer; the message says which argument and what is wrong."""

    user_facing = True


@dataclasses.dataclass
class RenderOutput:
    """One rendered view. ``w_i = alpha_i * T_i`` are the front-to-back compositing weights."""

    color: torch.Tensor | None  # [H, W, 3]  sum_i w_i c_i + (1 - alpha) * background
    features: torch.Tensor | None  # [H, W, D]  sum_i w_i f_i (not normalised, no background)
    depth: torch.Tensor  # [H, W]  sum_i w_i z_i / alpha (camera z), 0 where alpha ~ 0
    alpha: torch.Tensor  # [H, W]  sum_i w_i
    # projection data of the render (None where a backend has none):
    means2d: torch.Tensor | None = None  # [N, 2] pixel centres in the autograd graph: after
    #   retain_grad() and backward, .grad is 3DGS's screen-space gradient (densification)
    radii: torch.Tensor | None = None  # [N] int64 screen radius in pixels, 0 = culled


@dataclasses.dataclass
class PixelWeights:
    """Per-pixel contributing gaussians and their weights, as CSR rows (one row per pixel).

    For frozen geometry, the rendered features at ``pixels`` equal
    ``segment_sum(weights[:, None] * features[indices], indptr)``.
    """

    pixels: torch.Tensor  # [P] int64 linear pixel ids (row * W + col)
    indptr: torch.Tensor  # [P + 1] int64
    indices: torch.Tensor  # [nnz] int64 gaussian ids, front to back within a row
    weights: torch.Tensor  # [nnz] float32

    def render(self, features: torch.Tensor) -> torch.Tensor:
        """[N, D] per-gaussian features -> [P, D] rendered features at ``pixels``."""
        rows = torch.repeat_interleave(
            torch.arange(len(self.pixels), device=self.indptr.device), self.indptr.diff()
        )
        contrib = self.weights.to(features.dtype)[:, None] * features[self.indices]
        out = features.new_zeros(len(self.pixels), features.shape[1])
        return out.index_add(0, rows, contrib)
