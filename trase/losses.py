"""Photometric losses of 3DGS-style training: L1, SSIM (11x11 gaussian window, sigma 1.5), PSNR.

Images are [H, W, C] or [B, H, W, C] float tensors in [0, 1] (channels last, as the
rasterizer returns them).
"""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F


def _check_pair(pred: torch.Tensor, target: torch.Tensor, what: str) -> None:
    if pred.shape != target.shape:
        raise ValueError(f"{what}: prediction {tuple(pred.shape)} and target {tuple(target.shape)} differ in shape")
    if pred.dim() not in (3, 4):
        raise ValueError(f"{what}: expected [H, W, C] or [B, H, W, C], got {tuple(pred.shape)}")


def l1_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    _check_pair(pred, target, "l1_loss")
    return (pred - target).abs().mean()


@functools.lru_cache(maxsize=8)
def _gauss_1d(size: int, sigma: float, dtype: torch.dtype) -> torch.Tensor:
    """[size] normalised 1D gaussian; the 2D window of 3DGS is its outer product."""
    x = torch.arange(size, dtype=torch.float64) - (size // 2)
    g = torch.exp(-(x * x) / (2 * sigma * sigma))
    return (g / g.sum()).to(dtype)


def _blur(t: torch.Tensor, size: int, sigma: float) -> torch.Tensor:
    """Gaussian filter of [B, C, H, W] with zero padding size // 2, as two 1D passes
    (equal to the 2D window because it is separable, and ~size/2 times cheaper)."""
    c = t.shape[1]
    g = _gauss_1d(size, sigma, t.dtype).to(t.device)
    pad = size // 2
    t = F.conv2d(t, g.view(1, 1, 1, size).expand(c, 1, 1, size), padding=(0, pad), groups=c)
    return F.conv2d(t, g.view(1, 1, size, 1).expand(c, 1, size, 1), padding=(pad, 0), groups=c)


def ssim(pred: torch.Tensor, target: torch.Tensor, window_size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM as 3DGS computes it: per-channel gaussian-window statistics with zero
    padding of window_size // 2 (so the output keeps the image size), C1 = 0.01^2,
    C2 = 0.03^2, averaged over all pixels and channels."""
    _check_pair(pred, target, "ssim")
    if pred.dim() == 3:
        pred, target = pred[None], target[None]
    x = pred.permute(0, 3, 1, 2)  # [B, C, H, W]
    y = target.permute(0, 3, 1, 2)
    c = x.shape[1]
    # all five local statistics in one filtering pass: [B, 5C, H, W]
    stats = _blur(torch.cat([x, y, x * x, y * y, x * y], dim=1), window_size, sigma)
    mu_x, mu_y, e_xx, e_yy, e_xy = stats.split(c, dim=1)
    mu_x2, mu_y2, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
    s_x, s_y, s_xy = e_xx - mu_x2, e_yy - mu_y2, e_xy - mu_xy
    c1, c2 = 0.01**2, 0.03**2
    m = ((2 * mu_xy + c1) * (2 * s_xy + c2)) / ((mu_x2 + mu_y2 + c1) * (s_x + s_y + c2))
    return m.mean()


def ssim_reference(pred: torch.Tensor, target: torch.Tensor, window_size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Plain 2D-window SSIM (five separate convolutions, as 3DGS writes it); tests compare
    ``ssim`` against it."""
    _check_pair(pred, target, "ssim")
    if pred.dim() == 3:
        pred, target = pred[None], target[None]
    x = pred.permute(0, 3, 1, 2)
    y = target.permute(0, 3, 1, 2)
    c = x.shape[1]
    g = _gauss_1d(window_size, sigma, x.dtype).to(x.device)
    w = (g[:, None] @ g[None, :]).expand(c, 1, window_size, window_size)
    conv = lambda t: F.conv2d(t, w, padding=window_size // 2, groups=c)
    mu_x, mu_y = conv(x), conv(y)
    s_x = conv(x * x) - mu_x**2
    s_y = conv(y * y) - mu_y**2
    s_xy = conv(x * y) - mu_x * mu_y
    c1, c2 = 0.01**2, 0.03**2
    m = ((2 * mu_x * mu_y + c1) * (2 * s_xy + c2)) / ((mu_x**2 + mu_y**2 + c1) * (s_x + s_y + c2))
    return m.mean()


def dssim_l1_loss(pred: torch.Tensor, target: torch.Tensor, lambda_dssim: float = 0.2) -> torch.Tensor:
    """(1 - lambda) * L1 + lambda * (1 - SSIM): the Deformable-3DGS photometric loss."""
    return (1.0 - lambda_dssim) * l1_loss(pred, target) + lambda_dssim * (1.0 - ssim(pred, target))


def psnr(pred: torch.Tensor, target: torch.Tensor, max_value: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB over all pixels and channels (inf for identical)."""
    _check_pair(pred, target, "psnr")
    return psnr_of_mse(float(mean_squared_error(pred, target)), max_value)


def mean_squared_error(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """[] float64 on the inputs' device, no gradient: read it later to keep a GPU loop free of
    host synchronisations (``psnr_of_mse`` turns it into dB)."""
    return ((pred.detach().double() - target.detach().double()) ** 2).mean()


def psnr_of_mse(mse: float, max_value: float = 1.0) -> float:
    """dB of a mean squared error (inf for 0)."""
    if mse == 0.0:
        return math.inf
    return 10.0 * math.log10(max_value * max_value / mse)


def opacity_entropy(opacities: torch.Tensor) -> torch.Tensor:
    """Mean binary entropy (nats) of opacities [N] in [0, 1]: 0 when every one is 0 or 1."""
    o = opacities.clamp(1e-6, 1.0 - 1e-6)
    return -(o * torch.log(o) + (1.0 - o) * torch.log1p(-o)).mean()
