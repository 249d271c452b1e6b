"""Dynamic reconstruction: canonical gaussians + Deformable-3DGS deformation, trained on CPU.

The schedule is Deformable-3DGS's: gaussians initialised from the scene's points, a warm-up
without deformation, densification (clone / split by screen-space gradient) and pruning,
periodic opacity resets, one more SH band every 1000 iterations, L1 + D-SSIM loss, and a
time-noise on the deformation input annealed to zero. Checkpoints use the public layout
(``trase.checkpoint``) plus a sidecar with optimizer and schedule state, so an interrupted
run resumes where it stopped.

Deviations from the public trainer (documented because they change numbers slightly):
* the cpu presets' densification statistic (``densify_statistic="lstsq"``) is recovered from
  the gradient of the deformed 3D means by least squares through the projection Jacobian (it
  also counts what reaches a mean through its 2D covariance), in NDC units like 3DGS's; the
  ``paper`` preset uses the render's screen positions' gradient, as 3DGS does;
* the time-noise scale uses 1 / (number of training views) rather than 1 / (views left in the
  current random pass);
* ``max_gaussians`` caps densification (keeping the largest-gradient candidates).

Beside it: the settings and schedules (``trase.reconstruction_config``), the training images
(``trase.training_images``), densification (``trase.densify``: ``DensifyStrategy``), the
log and progress bar (``trase.training_log``).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from trase.camera import Camera
from trase.checkpoint import (
    CheckpointError,
    atomic_torch_save,
    available_iterations,
    load_model,
    save_model,
)
from trase.deformation import DeformMLP, deformed, deformed_visible
from trase.densify import DensifyStrategy, in_view, scene_extent
from trase.devices import resolve_device
from trase.gaussians import GaussianModel
from trase.io import read_torch
from trase.losses import l1_loss, opacity_entropy, psnr, ssim
from trase.reconstruction_config import ReconstructionConfig, expon_lr, time_noise_scale
from trase.training_images import ImageCache, load_image
from trase.training_log import ProgressBar, TrainLog


# -- rendering ------------------------------------------------------------------------------
def render_view(gaussians: GaussianModel, deformation, camera: Camera, background=None,
                backend: str = "auto", time_offset: float = 0.0, with_deform: bool = True,
                visible_only: bool = False):
    """Render gaussians deformed to camera.time. Returns (RenderOutput, deformed means [N,3]).

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
        background=background, backend=backend,
    )
    return out, means


@torch.no_grad()
def evaluate_psnr(gaussians: GaussianModel, deformation, views: Sequence, background=None,
                  backend: str = "auto", downscale: float = 1.0) -> float:
    """Mean over views of the PSNR (dB) of the clamped render against the view's image."""
    if not views:
        raise ValueError("evaluate_psnr: no views")
    bg = torch.zeros(3) if background is None else torch.as_tensor(background, dtype=torch.float32).cpu()
    dev = gaussians.means.device
    vals = []
    for v in views:
        cam = v.camera if downscale == 1 else v.camera.scaled(downscale)
        gt = torch.from_numpy(load_image(Path(v.image_path), cam, bg.numpy())).to(dev)
        out, _ = render_view(gaussians, deformation, cam, bg.to(dev), backend)
        vals.append(psnr(out.color.clamp(0, 1), gt))
    return float(np.mean(vals))


# -- training --------------------------------------------------------------------------------
def _make_optimizers(g: GaussianModel, deform: DeformMLP, cfg: ReconstructionConfig):
    groups = [
        {"params": [g.means], "lr": cfg.position_lr_init * cfg.spatial_lr_scale, "name": "means"},
        {"params": [g.sh_dc], "lr": cfg.feature_lr, "name": "sh_dc"},
        {"params": [g.sh_rest], "lr": cfg.feature_lr / 20.0, "name": "sh_rest"},
        {"params": [g.opacity_logits], "lr": cfg.opacity_lr, "name": "opacity_logits"},
        {"params": [g.log_scales], "lr": cfg.scaling_lr, "name": "log_scales"},
        {"params": [g.quats], "lr": cfg.rotation_lr, "name": "quats"},
    ]
    opt_g = torch.optim.Adam(groups, lr=0.0, eps=1e-15, fused=True)
    opt_d = torch.optim.Adam(
        [{"params": list(deform.parameters()), "lr": cfg.position_lr_init * cfg.spatial_lr_scale, "name": "deform"}],
        lr=0.0, eps=1e-15, fused=True,
    )
    return opt_g, opt_d


def _state_path(out_dir: Path, iteration: int) -> Path:
    return out_dir / "trainer_state" / f"iteration_{iteration}.pt"


def reconstruct(
    views: Sequence,
    points: np.ndarray,
    point_colors: np.ndarray | None,
    config: ReconstructionConfig,
    out_dir: str | Path,
    resume: bool = True,
    progress: bool = True,
    backend: str = "auto",
    max_seconds: float | None = None,
    torch_threads: int | None = None,
) -> tuple[GaussianModel, DeformMLP]:
    """Train canonical gaussians and a deformation MLP on ``views`` (objects with .camera, a
    pinhole Camera whose .time is the frame time, and .image_path).

    Checkpoints go to out_dir in the public layout every ``checkpoint_interval`` iterations
    and at the end; with ``resume`` the latest one (with its sidecar state) is continued.
    ``max_seconds`` stops early (and checkpoints) once that much wall time has been spent.
    ``torch_threads`` sets torch's intra-op threads for the run (restored afterwards); None
    takes ``config.torch_threads``.
    """
    old_threads = torch.get_num_threads()
    if torch_threads is None:
        torch_threads = config.torch_threads
    if torch_threads is not None:
        torch.set_num_threads(max(1, int(torch_threads)))
    try:
        return _reconstruct(views, points, point_colors, config, Path(out_dir), resume, progress, backend, max_seconds)
    finally:
        torch.set_num_threads(old_threads)


def _reconstruct(views, points, point_colors, config, out_dir, resume, progress, backend, max_seconds):
    cfg = config
    if not views:
        raise ValueError("reconstruct: no training views")
    dev = resolve_device(cfg.device)
    bg_np = np.ones(3, np.float32) if cfg.white_background else np.zeros(3, np.float32)
    bg = torch.from_numpy(bg_np).to(dev)
    data = ImageCache(views, cfg.image_downscale, bg_np, dev)
    strategy = DensifyStrategy(cfg, scene_extent(data.cameras))
    n_views = len(data)

    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    start = 0
    existing = available_iterations(out_dir) if resume else []
    if existing:
        start = existing[-1]
        gaussians, deform = load_model(out_dir, start)
        if deform is None:
            raise CheckpointError(f"{out_dir}: checkpoint {start} has no deformation network to resume")
        gaussians, deform = gaussians.to(dev), deform.to(dev)
        sp = _state_path(out_dir, start)
        if not sp.is_file():
            raise CheckpointError(f"{sp}: trainer state for iteration {start} is missing; cannot resume")
        state = read_torch(sp, CheckpointError, "unreadable trainer state")
        need = ["active_sh_degree", "opt_g", "opt_d", *DensifyStrategy.STATE_KEYS, "rng", "view_stack",
                "ema_loss", "ema_psnr"]
        lost = [k for k in need if not isinstance(state, dict) or k not in state]
        if lost:
            raise CheckpointError(f"{sp}: trainer state lacks {', '.join(lost)}")
        try:
            strategy.load_state_dict(state, gaussians.num_gaussians, dev)
        except ValueError as exc:
            raise CheckpointError(f"{sp}: {exc}") from None
        gaussians.active_sh_degree = int(state["active_sh_degree"])
        deform.train()
        opt_g, opt_d = _make_optimizers(gaussians, deform, cfg)
        opt_g.load_state_dict(state["opt_g"])
        opt_d.load_state_dict(state["opt_d"])
        gen.set_state(state["rng"])
        view_stack = [int(i) for i in state["view_stack"]]
        ema_loss, ema_psnr = float(state["ema_loss"]), float(state["ema_psnr"])
    else:
        gaussians = GaussianModel.from_points(points, point_colors, sh_degree=cfg.sh_degree)
        deform = DeformMLP.preset(cfg.deform_preset)
        if cfg.deform_zero_init:
            deform.zero_heads()
        gaussians, deform = gaussians.to(dev), deform.to(dev)  # initialised on the CPU: alike everywhere
        opt_g, opt_d = _make_optimizers(gaussians, deform, cfg)
        strategy.initialize_state(gaussians.num_gaussians, dev)
        view_stack = []
        ema_loss, ema_psnr = 0.0, 0.0

    def save(it: int) -> None:
        state = {
            "iteration": it,
            "active_sh_degree": gaussians.active_sh_degree,
            "opt_g": opt_g.state_dict(),
            "opt_d": opt_d.state_dict(),
            **strategy.state_dict(),
            "rng": gen.get_state(),
            "view_stack": torch.tensor(view_stack, dtype=torch.int64),
            "ema_loss": ema_loss, "ema_psnr": ema_psnr,
        }
        atomic_torch_save(state, _state_path(out_dir, it))
        save_model(out_dir, gaussians, deform, it, white_background=cfg.white_background)  # PLY last: marks it complete

    log = TrainLog(out_dir / "train_log.csv", start)
    bar = ProgressBar(progress, cfg.iterations, start)
    t0, c0 = time.perf_counter(), time.process_time()
    it = start
    try:
        for it in range(start + 1, cfg.iterations + 1):
            # learning rates
            for grp in opt_g.param_groups:
                if grp["name"] == "means":
                    grp["lr"] = expon_lr(it, cfg.position_lr_init * cfg.spatial_lr_scale,
                                         cfg.position_lr_final * cfg.spatial_lr_scale, cfg.position_lr_max_steps)
            opt_d.param_groups[0]["lr"] = expon_lr(it, cfg.position_lr_init * cfg.spatial_lr_scale,
                                                   cfg.position_lr_final, cfg.deform_lr_max_steps)
            if cfg.sh_interval > 0 and it % cfg.sh_interval == 0:
                gaussians.active_sh_degree = min(gaussians.active_sh_degree + 1, gaussians.max_sh_degree)

            if not view_stack:
                view_stack = torch.randperm(n_views, generator=gen).tolist()
            vi = view_stack.pop()
            cam, gt = data.cameras[vi], data.images[vi]

            use_deform = it >= cfg.warm_up
            offset = 0.0
            if use_deform:
                noise = float(torch.randn(1, generator=gen))
                offset = noise * time_noise_scale(it, cfg) / n_views
            out, means_t = render_view(gaussians, deform, cam, bg, backend, offset, use_deform,
                                       visible_only=cfg.deform_visible_only)
            strategy.step_pre_backward(out, means_t)
            image = out.color
            l1 = l1_loss(image, gt)
            loss = (1.0 - cfg.lambda_dssim) * l1 + cfg.lambda_dssim * (1.0 - ssim(image, gt))
            if cfg.opacity_entropy_weight > 0 and it >= cfg.opacity_entropy_from:
                loss = loss + cfg.opacity_entropy_weight * opacity_entropy(gaussians.opacities)
            loss.backward()

            with torch.no_grad():
                lv = float(loss)
                pv = psnr(image.clamp(0, 1), gt)
                ema_loss = lv if it == 1 else 0.4 * lv + 0.6 * ema_loss
                ema_psnr = pv if it == 1 else 0.4 * pv + 0.6 * ema_psnr
                if it % cfg.log_interval == 0 or it == cfg.iterations:
                    bar.update(it, f"loss {ema_loss:.4f}  psnr {ema_psnr:.2f} dB  N={gaussians.num_gaussians}")
                    log.write(it, ema_loss, ema_psnr, gaussians.num_gaussians, time.perf_counter() - t0,
                              time.process_time() - c0)

                strategy.step_post_backward(it, gaussians, opt_g, out, means_t, cam, gen)

                opt_g.step()
                opt_g.zero_grad(set_to_none=True)
                if use_deform:
                    opt_d.step()
                opt_d.zero_grad(set_to_none=True)

            if it % cfg.checkpoint_interval == 0 or it == cfg.iterations:
                save(it)
            if max_seconds is not None and time.perf_counter() - t0 > max_seconds:
                if it % cfg.checkpoint_interval != 0 and it != cfg.iterations:
                    save(it)
                break
    finally:
        bar.close()
        log.close()
    deform.eval()
    return gaussians, deform


