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
log and progress bar (``trase.training_log``), the renders and their image measures
(``trase.render_views``), the static gaussians' checks (``trase.static_checks``), the
trainer's state and its file beside each checkpoint (``trase.trainer``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from trase.camera import Camera
from trase.checkpoint import available_iterations
from trase.convergence import (
    STOP_FILE,
    held_out_indices,
    none_held_out,
    view_name,
    write_summary,
)
from trase.deformation import DeformMLP
from trase.densify import DensifyStrategy, scene_extent
from trase.devices import resolve_device
from trase.gaussians import GaussianModel
from trase.losses import l1_loss, mean_squared_error, opacity_entropy, psnr, ssim
from trase.reconstruction_config import ReconstructionConfig, expon_lr, time_noise_scale
from trase.render_views import render_view
from trase.resolution_schedule import config_schedule, scaled_views
from trase.static_checks import check_static, restart_static_checks
from trase.trainer import Trainer, new_trainer, resumed_trainer, save_trainer
from trase.training_images import ImageCache
from trase.training_log import ProgressBar, TrainLog

if TYPE_CHECKING:
    from trase.render.types import RenderOutput


# -- training --------------------------------------------------------------------------------
def is_motionless(views: Sequence) -> bool:
    """Every view at one time (a static capture, ``capture.time=static``): nothing for a
    deformation network to learn, so the scene trains as plain 3DGS."""
    times = {round(float(v.camera.time), 9) for v in views}
    return len(times) <= 1


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
) -> tuple[GaussianModel, DeformMLP | None]:
    """Train canonical gaussians and a deformation MLP on ``views`` (objects with .camera, a
    pinhole Camera whose .time is the frame time, and .image_path). A motionless capture
    (every view at one time, ``is_motionless``) trains plain 3DGS: no network, None returned.

    Checkpoints go to out_dir in the public layout every ``checkpoint_interval`` iterations
    and at the end; with ``resume`` the latest one (with its sidecar state) is continued.
    ``max_seconds`` stops early (and checkpoints) once that much wall time has been spent.
    With ``stop_interval`` > 0 some training views are held out and the run stops once their
    PSNR has stopped rising (``trase.convergence``); out_dir/stopped.json records the checks.
    ``torch_threads`` sets torch's intra-op threads for the run (restored afterwards); None
    takes ``config.torch_threads``.
    """
    from trase.threads import torch_threads as threads_for

    n = config.torch_threads if torch_threads is None else torch_threads
    with threads_for(None if n is None else max(1, int(n))):
        return _reconstruct(views, points, point_colors, config, Path(out_dir), resume, progress, backend, max_seconds)


def _reconstruct(views, points, point_colors, config, out_dir, resume, progress, backend, max_seconds):
    """reconstruct's body: data, then a new or resumed trainer, then the loop."""
    cfg = config
    if not views:
        raise ValueError("reconstruct: no training views")
    dev = resolve_device(cfg.device)
    bg_np = np.ones(3, np.float32) if cfg.white_background else np.zeros(3, np.float32)
    bg = torch.from_numpy(bg_np).to(dev)
    out = set(held_out_indices(views, cfg.stop_holdout_every)) if _first_check(cfg) is not None else set()
    held = [v for i, v in enumerate(views) if i in out]  # held out of training for the stopping criterion
    views = [v for i, v in enumerate(views) if i not in out]
    held_data = ImageCache(held, cfg.image_downscale, bg_np, dev) if held else None
    data = ImageCache(views, cfg.image_downscale, bg_np, dev)
    strategy = DensifyStrategy(cfg, scene_extent(data.cameras))

    torch.manual_seed(cfg.seed)  # the network's initialisation
    gen = torch.Generator().manual_seed(cfg.seed)
    existing = available_iterations(out_dir) if resume else []
    start = existing[-1] if existing else 0
    static = is_motionless(views)
    if existing:
        tr = resumed_trainer(out_dir, start, cfg, dev, strategy, gen, static)
    else:
        tr = new_trainer(points, point_colors, cfg, dev, strategy, gen, static)
    if not held:
        tr.plateau = None  # none held out (too few views, or no stop possible): the full schedule
    schedule = config_schedule(data, cfg, len(points))
    tr.scaled = scaled_views(data, cfg, schedule)
    strategy.cap_at = schedule.cap_at if schedule is not None else None
    if tr.plateau is None or tr.plateau.stopped_at is None:  # a run that stopped when converged is done
        _train(tr, data, bg, cfg, out_dir, start, progress, backend, max_seconds, held_data)
    if cfg.stop_interval > 0:
        summary = (tr.plateau.summary("held-out PSNR (dB)", cfg.iterations, [view_name(v) for v in held])
                   if tr.plateau is not None else none_held_out(cfg.iterations, (
                       f"fewer than {2 * cfg.stop_holdout_every} training views: none held out, the full schedule"
                       if _first_check(cfg) is not None else
                       f"no stop possible between the warm-up's end and the schedule's ({cfg.iterations}): none held out")))
        write_summary(out_dir / STOP_FILE, summary)
    else:
        (out_dir / STOP_FILE).unlink(missing_ok=True)  # an earlier run's, with stopping on
    if tr.deform is not None:
        tr.deform.eval()
    return tr.gaussians, tr.deformation()


def _train(tr: Trainer, data: ImageCache, bg: torch.Tensor, cfg: ReconstructionConfig, out_dir: Path,
           start: int, progress: bool, backend: str, max_seconds: float | None,
           held: ImageCache | None = None) -> None:
    """Iterations start + 1 .. cfg.iterations: a step, its bookkeeping, checkpoints; stops
    early (after a checkpoint) once ``max_seconds`` have passed, or once the PSNR of the
    ``held`` views (their images, loaded once) has stopped rising (``tr.plateau``)."""
    log = TrainLog(out_dir / "train_log.csv", start)
    restart_static_checks(out_dir, start)
    bar = ProgressBar(progress, cfg.iterations, start)
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        for it in range(start + 1, cfg.iterations + 1):
            step = _forward_backward(tr, it, data, bg, cfg, backend)
            with torch.no_grad():
                _record(tr, it, step)
                if it % cfg.log_interval == 0 or it == cfg.iterations:
                    tr.fold()
                    n = tr.gaussians.num_gaussians
                    static = f"  static {tr.n_static / max(n, 1):.0%}" if tr.static is not None else ""
                    bar.update(it, f"loss {tr.ema_loss:.4f}  psnr {tr.ema_psnr:.2f} dB  N={n}{static}")
                    log.write(it, tr.ema_loss, tr.ema_psnr, n, time.perf_counter() - t0, time.process_time() - c0,
                              tr.n_static)
                carry = None if tr.static is None else {"static": tr.static, "frozen": tr.frozen}
                carry = tr.strategy.step_post_backward(it, tr.gaussians, tr.opt_g, step.out, step.means, step.camera,
                                                       tr.gen, carry)
                if carry is not None:
                    tr.static, tr.frozen = carry["static"], carry["frozen"]
                _optimizer_step(tr, step.use_deform)
                check_static(tr, it, cfg, data, bg, backend, out_dir)
                converged = _converged(tr, it, cfg, held, bg, backend)
            if _checkpoint(tr, out_dir, it, cfg, t0, max_seconds, converged):
                break
    finally:
        bar.close()
        log.close()


def _first_check(cfg: ReconstructionConfig) -> int | None:
    """The first iteration the stopping rule checks (a multiple of stop_interval, from the
    warm-up's end), None when stopping is off or no stop could come before the schedule ends."""
    if cfg.stop_interval <= 0:
        return None
    first = max(-(-cfg.warm_up // cfg.stop_interval), 1) * cfg.stop_interval
    return first if cfg.stop_rule().can_stop_before(cfg.iterations, first) else None


def _converged(tr: Trainer, it: int, cfg: ReconstructionConfig, held: ImageCache | None, bg: torch.Tensor,
               backend: str) -> bool:
    """On the stopping schedule (past the warm-up): the held-out views' mean PSNR (the clamped
    renders, as ``evaluate_images`` measures it), recorded; True when the run should stop after
    this iteration."""
    if tr.plateau is None or held is None or it < cfg.warm_up or not tr.plateau.due(it):
        return False
    deformation = tr.deformation()
    value = float(np.mean([psnr(render_view(tr.gaussians, deformation, cam, bg, backend, near=cfg.near_plane)[0]
                                .color.clamp(0, 1), gt)
                           for cam, gt in zip(held.cameras, held.images)]))
    return tr.plateau.observe(it, value, cap=cfg.iterations)


def _checkpoint(tr: Trainer, out_dir: Path, it: int, cfg: ReconstructionConfig, t0: float,
                max_seconds: float | None, converged: bool = False) -> bool:
    """Save on the checkpoint schedule, at the end and where the run ``converged`` (then True:
    stop); True (stop) once ``max_seconds`` have passed since ``t0`` (time.perf_counter),
    counting the save, after saving this iteration."""
    due = it % cfg.checkpoint_interval == 0 or it == cfg.iterations or converged
    if due:
        save_trainer(tr, out_dir, it, cfg)
    if converged:
        return True
    if max_seconds is not None and time.perf_counter() - t0 > max_seconds:
        if not due:
            save_trainer(tr, out_dir, it, cfg)
        return True
    return False


@dataclasses.dataclass
class _Step:
    """What one iteration's forward pass leaves for the bookkeeping after its backward."""

    camera: Camera
    gt: torch.Tensor  # [H, W, 3] the view's image
    out: RenderOutput  # the render (out.color [H, W, 3]; means2d, radii [N] for densification)
    means: torch.Tensor  # [N, 3] deformed means the view was rendered with
    loss: torch.Tensor  # [] after backward
    use_deform: bool  # past the warm-up: the network trains this step


def _schedule(tr: Trainer, it: int, cfg: ReconstructionConfig) -> None:
    """Iteration ``it``'s learning rates (means and network decay exponentially) and SH band."""
    for grp in tr.opt_g.param_groups:
        if grp["name"] == "means":
            grp["lr"] = expon_lr(it, cfg.position_lr_init * cfg.spatial_lr_scale,
                                 cfg.position_lr_final * cfg.spatial_lr_scale, cfg.position_lr_max_steps)
    if tr.opt_d is not None:
        tr.opt_d.param_groups[0]["lr"] = expon_lr(it, cfg.position_lr_init * cfg.spatial_lr_scale,
                                                  cfg.position_lr_final, cfg.deform_lr_max_steps)
    if cfg.sh_interval > 0 and it % cfg.sh_interval == 0:
        g = tr.gaussians
        g.active_sh_degree = min(g.active_sh_degree + 1, g.max_sh_degree)


def _forward_backward(tr: Trainer, it: int, data: ImageCache, bg: torch.Tensor, cfg: ReconstructionConfig,
                      backend: str) -> _Step:
    """Iteration ``it`` up to its backward: the next view of the random pass, rendered at its
    time plus the annealed time noise (after the warm-up), L1 + D-SSIM (+ opacity entropy)."""
    _schedule(tr, it, cfg)
    n_views = len(data)
    if not tr.view_stack:
        tr.view_stack = torch.randperm(n_views, generator=tr.gen).tolist()
    vi = tr.view_stack.pop()
    cam, gt = tr.scaled.view(vi, it) if tr.scaled is not None else (data.cameras[vi], data.images[vi])

    use_deform = tr.deform is not None and it >= cfg.warm_up
    offset = 0.0
    if use_deform:
        noise = float(torch.randn(1, generator=tr.gen))
        offset = noise * time_noise_scale(it, cfg) / n_views
    out, means_t = render_view(tr.gaussians, tr.deformation(), cam, bg, backend, offset, use_deform,
                               visible_only=cfg.deform_visible_only, near=cfg.near_plane)
    tr.strategy.step_pre_backward(out, means_t)
    image = out.color  # [H, W, 3]
    loss = (1.0 - cfg.lambda_dssim) * l1_loss(image, gt) + cfg.lambda_dssim * (1.0 - ssim(image, gt))
    if cfg.opacity_entropy_weight > 0 and it >= cfg.opacity_entropy_from:
        loss = loss + cfg.opacity_entropy_weight * opacity_entropy(tr.gaussians.opacities)
    loss.backward()
    return _Step(cam, gt, out, means_t, loss, use_deform)


def _record(tr: Trainer, it: int, step: _Step) -> None:
    """Keep this step's loss and squared error (on the device) for the smoothed values the log
    shows (``Trainer.fold``)."""
    tr.pending.append((it, step.loss.detach(), mean_squared_error(step.out.color.clamp(0, 1), step.gt)))


def _optimizer_step(tr: Trainer, use_deform: bool) -> None:
    """Adam steps (the network's only past the warm-up), then the gradients cleared."""
    tr.opt_g.step()
    tr.opt_g.zero_grad(set_to_none=True)
    if tr.opt_d is None:
        return
    if use_deform:
        tr.opt_d.step()
    tr.opt_d.zero_grad(set_to_none=True)
