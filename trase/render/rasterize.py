"""The public rasterizer: ``rasterize`` (colour, features, depth, alpha) and ``pixel_weights``
(each pixel's contributing gaussians and weights, for the frozen-geometry fast path).

Pipeline: EWA projection (torch reference in projection.py; numba twin in numba_projection.py
for the numba backend) -> per-gaussian channels
(SH colour, features, camera z for depth) -> tile compositing (backend) -> split channels.
Backends: ``torch`` (reference, autograd), ``numba`` (fast CPU, hand-written backward),
``gsplat`` (CUDA only), ``auto`` (gsplat for CUDA tensors, numba otherwise).
"""

from __future__ import annotations

import dataclasses
import math

import torch

from trase.camera import Camera
from trase.render.channels import ALPHA_EPS, channel_parts
from trase.render.projection import project_gaussians
from trase.render.types import PixelWeights, RenderError, RenderOutput

BACKENDS = ("torch", "numba", "gsplat", "auto")
# NEAR_PLANE (trase.camera): a camera's near plane when it names none; a render culls at the
# camera's own (``Camera.near``) unless the caller names another


def _check_inputs(means, quats, scales, opacities, camera, colors, sh_degree, features, background):
    if not isinstance(camera, Camera):
        raise RenderError(f"rasterize: camera must be a trase.camera.Camera, got {type(camera).__name__}")
    if not camera.is_pinhole:
        raise RenderError(
            f"rasterize: camera {camera.name or '(unnamed)'} has lens distortion; "
            "undistort the images and use camera.undistorted()"
        )
    if means.ndim != 2 or means.shape[1] != 3:
        raise RenderError(f"rasterize: means must be [N, 3], got {tuple(means.shape)}")
    n = means.shape[0]
    for name, t, shape in (("quats", quats, (n, 4)), ("scales", scales, (n, 3)), ("opacities", opacities, (n,))):
        if tuple(t.shape) != shape:
            raise RenderError(f"rasterize: {name} must be {list(shape)}, got {list(t.shape)}")
    tensors = [means, quats, scales, opacities]
    if colors is not None:
        ok = (colors.ndim == 2 and tuple(colors.shape) == (n, 3)) or (
            colors.ndim == 3 and colors.shape[0] == n and colors.shape[2] == 3
        )
        if not ok:
            raise RenderError(f"rasterize: colors must be [N, 3] RGB or [N, K, 3] SH, got {list(colors.shape)}")
        if colors.ndim == 3:
            k = colors.shape[1]
            deg = sh_degree if sh_degree is not None else round(math.sqrt(k)) - 1
            if not 0 <= deg <= 3 or (deg + 1) ** 2 > k or (sh_degree is None and (deg + 1) ** 2 != k):
                raise RenderError(f"rasterize: {k} SH coefficients do not fit sh_degree={sh_degree} (0..3)")
        tensors.append(colors)
    if features is not None:
        if features.ndim != 2 or features.shape[0] != n:
            raise RenderError(f"rasterize: features must be [N, D], got {list(features.shape)}")
        tensors.append(features)
    if background is not None:
        if colors is None or background.numel() != 3:
            raise RenderError("rasterize: background must be [3] and needs colors")
        tensors.append(background)
    for t in tensors:
        if not t.is_floating_point():
            raise RenderError(f"rasterize: expected floating point tensors, got {t.dtype}")
        if t.device != means.device:
            raise RenderError(f"rasterize: all tensors must be on one device ({means.device} vs {t.device})")


def _resolve_backend(backend: str, device: torch.device) -> str:
    if backend not in BACKENDS:
        raise RenderError(f"rasterize: unknown backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    if backend == "auto":
        return "gsplat" if device.type == "cuda" else "numba"
    if backend == "gsplat" and device.type != "cuda":
        raise RenderError("rasterize: the gsplat backend needs CUDA tensors; use backend='numba' on CPU")
    if backend == "numba" and device.type != "cpu":
        raise RenderError("rasterize: the numba backend runs on CPU tensors only")
    return backend


def rasterize(
    means: torch.Tensor,  # [N, 3]
    quats: torch.Tensor,  # [N, 4] wxyz, any norm
    scales: torch.Tensor,  # [N, 3] positive (already exp'd)
    opacities: torch.Tensor,  # [N] in [0, 1] (already sigmoid'd)
    camera: Camera,
    colors: torch.Tensor | None = None,  # [N, 3] RGB or [N, (d+1)^2, 3] SH
    sh_degree: int | None = None,
    features: torch.Tensor | None = None,  # [N, D]
    background: torch.Tensor | None = None,  # [3], colour only
    backend: str = "auto",
    near: float | None = None,  # None: the camera's near plane
    tile_size: int = 16,
) -> RenderOutput:
    """Render one view; differentiable w.r.t. every tensor argument (torch and numba). The
    output carries the projection (``means2d``, ``radii``), so a trainer needs no second one."""
    _check_inputs(means, quats, scales, opacities, camera, colors, sh_degree, features, background)
    near = camera.near if near is None else near
    backend = _resolve_backend(backend, means.device)
    if backend == "gsplat":
        from trase.render.gsplat_backend import rasterize_gsplat

        return rasterize_gsplat(
            means, quats, scales, opacities, camera, colors, sh_degree, features, background, near
        )
    if tile_size <= 0:
        raise RenderError(f"rasterize: tile_size must be positive, got {tile_size}")
    dtype = means.dtype
    if backend == "torch":
        proj = project_gaussians(means, quats, scales, camera, near=near, tile_size=tile_size, dtype=dtype)
    else:
        from trase.render.numba_projection import project_gaussians_numba

        proj = project_gaussians_numba(means, quats, scales, camera, near=near, tile_size=tile_size, dtype=dtype)
    parts = channel_parts(colors, sh_degree, features, means, camera, dtype)
    channels = torch.cat([*parts, proj.depths[:, None]], dim=1)  # [N, C] = colour | features | z
    opac = opacities.to(dtype)
    if backend == "torch":
        from trase.render.torch_backend import composite_torch

        out, alpha = composite_torch(
            proj.means2d, proj.conics, opac, channels, proj.depths, proj.rects,
            camera.width, camera.height, tile_size,
        )
    else:
        from trase.render.numba_backend import composite_numba

        out, alpha = composite_numba(
            proj.means2d, proj.conics, opac, channels, proj.depths, proj.rects,
            camera.width, camera.height, tile_size,
        )
    render = _split(out, alpha, colors is not None, features.shape[1] if features is not None else 0, background)
    return dataclasses.replace(render, means2d=proj.means2d, radii=proj.radii)


def _split(out, alpha, has_color, n_feat, background) -> RenderOutput:
    """out [H, W, C] (colour | features | z) and alpha [H, W] -> RenderOutput. One split (its
    backward is one concatenation, where separate slices would each scatter into zeros)."""
    sizes = [3] * has_color + [n_feat] * (n_feat > 0) + [1]
    parts = list(out.split(sizes, dim=-1))
    color = parts.pop(0) if has_color else None
    feats = parts.pop(0) if n_feat else None
    z_sum = parts.pop(0)[..., 0]
    if color is not None and background is not None:
        color = color + (1.0 - alpha)[..., None] * background.to(out.dtype).reshape(3)
    has = alpha > ALPHA_EPS
    depth = torch.where(has, z_sum / torch.where(has, alpha, torch.ones_like(alpha)), torch.zeros_like(alpha))
    return RenderOutput(color=color, features=feats, depth=depth, alpha=alpha)


def pixel_weights(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    camera: Camera,
    pixels: torch.Tensor | None = None,  # [P] int64 linear ids row * W + col; None = all
    min_weight: float = 0.0,
    near: float | None = None,  # None: the camera's near plane
    tile_size: int = 16,
) -> PixelWeights:
    """Each pixel's contributing gaussians (front to back) and weights w = alpha * T, from the
    same binning and compositing rules as ``rasterize`` (computed on CPU with numba, returned
    on the input device). Not differentiable: it is for frozen geometry."""
    _check_inputs(means, quats, scales, opacities, camera, None, None, None, None)
    near = camera.near if near is None else near
    from trase.render.numba_backend import pixel_weights_numba

    dev = means.device
    hw = camera.width * camera.height
    if pixels is None:
        pix = torch.arange(hw, dtype=torch.int64)
    else:
        pix = torch.as_tensor(pixels).to("cpu", torch.int64).reshape(-1)
        if pix.numel() and (int(pix.min()) < 0 or int(pix.max()) >= hw):
            raise RenderError(f"pixel_weights: pixel ids must lie in [0, {hw}) for a {camera.width}x{camera.height} camera")
    with torch.no_grad():
        args = [t.detach().to("cpu") for t in (means, quats, scales, opacities)]
        from trase.render.numba_projection import project_gaussians_numba

        proj = project_gaussians_numba(*args[:3], camera, near=near, tile_size=tile_size, dtype=torch.float32)
        indptr, indices, weights = pixel_weights_numba(
            proj.means2d, proj.conics, args[3].to(torch.float32), proj.depths, proj.rects,
            camera.width, camera.height, tile_size, pix, float(min_weight),
        )
    return PixelWeights(pixels=pix.to(dev), indptr=indptr.to(dev), indices=indices.to(dev), weights=weights.to(dev))
