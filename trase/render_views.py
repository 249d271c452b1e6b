"""A model rendered at a view's time, and the field's image measures of such renders against the
views' images (PSNR, SSIM, LPIPS): what training, its checks and the benchmark's geometry stage
share."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from trase.camera import Camera
from trase.deformation import deformed, deformed_visible
from trase.densify import in_view
from trase.gaussians import GaussianModel
from trase.losses import psnr, ssim
from trase.training_images import load_image


def render_view(gaussians: GaussianModel, deformation, camera: Camera, background=None,
                backend: str = "auto", time_offset: float = 0.0, with_deform: bool = True,
                visible_only: bool = False, near: float | None = None):
    """Render gaussians deformed to camera.time. Returns (RenderOutput, deformed means [N,3]).
    ``near``: the rasterizer's near plane (``ReconstructionConfig.near_plane`` while training;
    None: the camera's).

    ``visible_only``: the deformation's gradients are computed for the gaussians the camera
    can see only (``deformation.deformed_visible``; same image and gradients up to rounding).
    """
    from trase.render import rasterize

    t = float(camera.time) + time_offset
    deform = deformation if with_deform else None
    if visible_only and deform is not None and gaussians.means.device.type == "cpu":
        means, quats, scales = deformed_visible(gaussians, deform, t, functools.partial(in_view, camera=camera))
    else:
        means, quats, scales = deformed(gaussians, deform, t)
    out = rasterize(
        means, quats, scales, gaussians.opacities, camera,
        colors=gaussians.sh_for_render(), sh_degree=gaussians.active_sh_degree,
        background=background, backend=backend, near=near,
    )
    return out, means


@torch.no_grad()
def evaluate_psnr(gaussians: GaussianModel, deformation, views: Sequence, background=None,
                  backend: str = "auto", downscale: float = 1.0, near: float | None = None) -> float:
    """Mean over views of the PSNR (dB) of the clamped render against the view's image."""
    if not views:
        raise ValueError("evaluate_psnr: no views")
    return evaluate_images(gaussians, deformation, views, background, backend, downscale, ssim_too=False,
                           near=near)["psnr"]


@torch.no_grad()
def evaluate_images(gaussians: GaussianModel, deformation, views: Sequence, background=None,
                    backend: str = "auto", downscale: float = 1.0, ssim_too: bool = True, lpips=None,
                    near: float | None = None) -> dict:
    """The field's image measures of the clamped renders against the views' images (alpha
    composited over ``background``, black by default, as in training): mean PSNR (dB) and mean
    SSIM (3DGS's 11x11 gaussian window, ``losses.ssim``) over the views, the views' PSNRs, and
    with ``lpips`` (a ``trase.lpips.LPIPS``) the mean LPIPS. ``near``: the near plane the
    geometry was trained with (``ReconstructionConfig.near_plane``; None: each view camera's)."""
    if not views:
        raise ValueError("evaluate_images: no views")
    bg = torch.zeros(3) if background is None else torch.as_tensor(background, dtype=torch.float32).cpu()
    dev = gaussians.means.device
    psnrs, ssims, lps = [], [], []
    for v in views:
        cam = v.camera if downscale == 1 else v.camera.scaled(downscale)
        gt = torch.from_numpy(load_image(Path(v.image_path), cam, bg.numpy())).to(dev)
        out, _ = render_view(gaussians, deformation, cam, bg.to(dev), backend, near=near)
        img = out.color.clamp(0, 1)
        psnrs.append(psnr(img, gt))
        if ssim_too:
            ssims.append(float(ssim(img, gt)))
        if lpips is not None:
            lps.append(lpips(img, gt))
    return {"psnr": float(np.mean(psnrs)), "ssim": float(np.mean(ssims)) if ssims else None,
            "lpips": float(np.mean(lps)) if lps else None, "per_view_psnr": [float(x) for x in psnrs]}


__all__ = ["evaluate_images", "evaluate_psnr", "render_view"]
