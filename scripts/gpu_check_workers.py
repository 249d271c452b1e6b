"""The GPU check's workers (scripts/gpu_check.py runs each in its own process, with PYTHONPATH
at the tree under test): ``profile`` times and profiles one reconstruction iteration,
``diagnose`` watches the default run's reconstruction. They live outside the package so that
the same harness measures an older checkout and this one."""

from __future__ import annotations

import dataclasses
import statistics
import time
from pathlib import Path


# -- the worker: one reconstruction iteration, timed and profiled ---------------------------
def profile(sizes: list[tuple[int, int, int]], device: str, repeats: int, tf32: bool = False) -> dict:
    """perf gpu's reconstruction iteration at each size with whatever trase is importable:
    median wall time over ``repeats`` steps, then a profile of 3 steps. ``tf32``: matrix
    products in TF32 (a diagnostic; no preset uses it). The step is written out here, not
    imported from benchmark.perf.gpu: the harness must be the same for the checkout before and
    this one, so it lives outside both."""
    import torch

    torch.backends.cuda.matmul.allow_tf32 = tf32
    cuda = device == "cuda"
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    rows = []
    for n, w, h in sizes:
        step = _iteration(n, w, h, device)
        for _ in range(3):
            step()
        sync()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            step()
            sync()
            times.append(time.perf_counter() - t0)
        if cuda:
            torch.cuda.reset_peak_memory_stats()
            step()
            sync()
        rows.append({"gaussians": n, "width": w, "height": h, "median_ms": round(1e3 * statistics.median(times), 3),
                     "min_ms": round(1e3 * min(times), 3),
                     "peak_gpu_mib": round(torch.cuda.max_memory_allocated() / 2**20, 1) if cuda else None,
                     **_profiled(step, sync, cuda)})
        del step  # the model and its optimizers with it
        if cuda:
            torch.cuda.empty_cache()
    import trase

    return {"device": torch.cuda.get_device_name() if cuda else "cpu", "repeats": repeats,
            "trase_from": str(Path(trase.__file__).parent), "tf32": tf32, "sizes": rows}


def _iteration(n: int, w: int, h: int, device: str):
    """perf gpu's reconstruction iteration as a callable: the deformation network, render,
    L1 + D-SSIM, backward, both Adam steps, on ``n`` gaussians at ``w`` x ``h``. A copy of
    benchmark.perf.gpu.reconstruction_step's step on any device, kept here on purpose: this
    harness also times older checkouts, whose perf module may differ or be missing."""
    import torch

    from benchmark.perf.raster import make_scene
    from trase.deformation import DeformMLP, deformed
    from trase.gaussians import GaussianModel
    from trase.losses import l1_loss, ssim
    from trase.reconstruct import ReconstructionConfig
    from trase.render import rasterize
    from trase.trainer import make_optimizers

    sc, cam = make_scene(n, w, h, 0)
    g = GaussianModel.from_points(sc["means"].numpy(), sc["colors"].numpy(), sh_degree=3).to(device)
    g.active_sh_degree = 3
    # zero heads: offsets as small as a trained network's (the random initialisation's
    # ~0.1-0.5 scene units make every gaussian cover hundreds of tiles, and the steps change them)
    deform = DeformMLP.preset("paper").zero_heads().to(device)
    opt_g, opt_d = make_optimizers(g, deform, ReconstructionConfig.paper())
    gt = torch.rand(h, w, 3, device=device)
    bg = torch.zeros(3, device=device)
    backend = "auto" if device == "cuda" else "torch"

    def step():
        m, q, s = deformed(g, deform, 0.5)
        out = rasterize(m, q, s, g.opacities, cam, colors=g.sh_for_render(), sh_degree=3, background=bg,
                        backend=backend)
        loss = 0.8 * l1_loss(out.color, gt) + 0.2 * (1.0 - ssim(out.color, gt))
        loss.backward()
        opt_g.step()
        opt_d.step()
        opt_g.zero_grad(set_to_none=True)
        opt_d.zero_grad(set_to_none=True)

    return step


def _profiled(step, sync, cuda: bool) -> dict:
    """Three steps under torch's profiler -> the aten calls and kernel launches per step, and
    the 15 costliest operations (device time on a GPU, CPU time otherwise)."""
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    with torch_profile(activities=activities) as prof:
        for _ in range(3):
            step()
        sync()
    events = prof.events()
    aten_top = [e for e in events if e.name.startswith("aten::")
                and (e.cpu_parent is None or not e.cpu_parent.name.startswith("aten::"))]
    launches = [e for e in events if e.name in ("cudaLaunchKernel", "cuLaunchKernel", "cudaLaunchKernelExC",
                                               "cuLaunchKernelEx")]
    key = "device_time_total" if cuda else "cpu_time_total"
    table = sorted(prof.key_averages(), key=lambda a: getattr(a, key, 0.0), reverse=True)
    top = [{"name": a.key[:80], "calls": a.count, "device_ms": round(getattr(a, "device_time_total", 0.0) / 3e3, 3),
            "cpu_ms": round(a.cpu_time_total / 3e3, 3)} for a in table[:15]]
    return {"aten_ops_per_step": len(aten_top) / 3, "kernel_launches_per_step": len(launches) / 3, "top_per_step": top}


# -- the worker: the default run's reconstruction, watched ---------------------------------
DIAG_VARIANTS = ("default", "torch-sh", "tf32", "cap", "lstsq")


def diagnose(seconds: float, variant: str, every: int = 100, until: int = 0,
             window: tuple[int, int] = (0, 0), near: float | None = None) -> dict:
    """The geometry stage of ``trase-bench run --method trase --dataset hypernerf`` (its
    resolved settings, on this machine's default device) for ``seconds``, with the model's
    state every ``every`` iterations: what grows or diverges, and when. Variants: ``torch-sh``
    evaluates SH in torch (the adapter before gsplat took it over), ``tf32`` runs the matrix
    products in TF32, ``cap`` caps the gaussians at two per pixel of a training image, ``lstsq``
    densifies by the statistic the cpu presets use. ``until``: stop after this iteration (the
    schedule is otherwise the run's); inside ``window`` (first, last iteration) every 10th
    iteration is recorded, and every iteration's loss. ``near``: the rasterizer's near plane while
    training (the run's ``geometry.train.near_plane`` when None). Each record also counts, over
    every training camera at its own time, the gaussians in its frustum nearer than 0.2 (the
    public rasterizer's cull), where a screen position moves as 1 / z^2 with depth; at the end
    the test PSNR and the geometry's label ceiling (the benchmark's ``ceiling`` stage, on the CPU)."""
    import tempfile

    import torch

    import trase.reconstruct as rec
    from benchmark.datasets import get_dataset, load_scene
    from benchmark.datasets.synthetic.cache import ensure_synthetic
    from benchmark.methods import get_method
    from benchmark.pipeline.settings import run_settings
    from trase.render_views import evaluate_psnr

    scene_dir = ensure_synthetic("hypernerf")
    scene = load_scene("hypernerf", scene_dir, gt_dir=scene_dir / "gt_masks")
    cam = scene.train[0].camera
    settings = run_settings(get_method("trase"), get_dataset("hypernerf"), "synthetic", {}, (cam.width, cam.height))
    cfg = _diag_config(settings.geometry.train, variant, until, near, cam)
    views = [(torch.as_tensor(c.w2c, dtype=torch.float32), 1.3 * c.width / (2 * c.fx), 1.3 * c.height / (2 * c.fy),
              float(c.time)) for c in (v.camera for v in scene.train)]
    torch.backends.cuda.matmul.allow_tf32 = variant == "tf32"
    if variant == "torch-sh":
        _use_torch_sh()
    rows: list[dict] = []
    losses: list[list] = []
    t0 = time.perf_counter()
    record = rec._record

    def watched(tr, it, step):
        record(tr, it, step)
        inside = window[0] <= it <= window[1]
        if inside:
            losses.append([it, round(float(step.loss), 5), round(float(step.camera.time), 4)])
        if it % (10 if inside else every) == 0:
            rows.append({"it": it, "s": round(time.perf_counter() - t0, 2), **_diag_row(tr, it, step, cfg, cam, views)})

    rec._record = watched
    with tempfile.TemporaryDirectory(prefix="gpu-diag-") as tmp:
        gaussians, deform = rec.reconstruct(scene.train, scene.points, scene.point_colors, cfg, Path(tmp) / "model",
                                            resume=False, progress=False, max_seconds=seconds)
        trained = round(time.perf_counter() - t0, 1)
        test_psnr = evaluate_psnr(gaussians, deform, scene.test, near=cfg.near_plane) if scene.test else None
        ceiling = _ceiling(Path(tmp), scene) if scene.truth is not None else None
    return {"variant": variant, "near_plane": cfg.near_plane, "config": dataclasses.asdict(cfg), "seconds": seconds,
            "trained_s": trained, "n_gaussians": int(gaussians.num_gaussians), "test_psnr": test_psnr,
            "ceiling": ceiling, "rows": rows, "window_losses": losses}


def _diag_config(cfg, variant: str, until: int, near: float | None, cam):
    """The run's reconstruction settings with the variant's change, the last iteration and the
    near plane asked for."""
    if variant == "cap":
        cfg = dataclasses.replace(cfg, max_gaussians=2 * cam.width * cam.height)
    if variant == "lstsq":
        cfg = dataclasses.replace(cfg, densify_statistic="lstsq")
    if until:
        cfg = dataclasses.replace(cfg, iterations=until)
    if near is not None:
        cfg = dataclasses.replace(cfg, near_plane=near)
    return cfg


def _use_torch_sh() -> None:
    """SH evaluated in torch before gsplat draws (the adapter before gsplat took it over)."""
    import trase.render.gsplat_backend as gb
    from trase.render.channels import gaussian_colors

    plain = gb.rasterize_gsplat

    def with_torch_sh(means, quats, scales, opacities, camera, colors, sh_degree, *rest):
        if colors is not None and colors.ndim == 3:
            colors, sh_degree = gaussian_colors(colors, sh_degree, means, camera), None
        return plain(means, quats, scales, opacities, camera, colors, sh_degree, *rest)

    gb.rasterize_gsplat = with_torch_sh


def _near_visible(step) -> int:
    """Gaussians this step drew (radius > 0) nearer than 0.2 to its camera."""
    import torch

    w = torch.as_tensor(step.camera.w2c, dtype=step.means.dtype, device=step.means.device)
    z = step.means.detach() @ w[2, :3] + w[2, 3]
    return int(((step.out.radii > 0) & (z < 0.2)).sum())


def _near_zone(tr, views: list, near_plane: float) -> dict:
    """Over every training camera at its time (``views``: (w2c, tan x, tan y, time)): the most
    gaussians in its frustum nearer than 0.2 (and of those, the most the run's plane still
    draws), the nearest in-frustum depth, and the time of the camera with the most."""
    from trase.deformation import deformed

    worst = {"near_zone_max": 0, "near_zone_time": None, "near_drawn_max": 0, "z_min": float("inf")}
    for w2c, tx, ty, t in views:
        m = deformed(tr.gaussians, tr.deformation(), t)[0]
        w = w2c.to(m.device)
        x = m @ w[:3, :3].T + w[:3, 3]
        z = x[:, 2]
        inside = (z > 1e-6) & (x[:, 0].abs() < tx * z) & (x[:, 1].abs() < ty * z)
        zone = int((inside & (z < 0.2)).sum())
        if zone > worst["near_zone_max"]:
            worst.update(near_zone_max=zone, near_zone_time=round(t, 4))
        worst["near_drawn_max"] = max(worst["near_drawn_max"], int((inside & (z < 0.2) & (z > near_plane)).sum()))
        if bool(inside.any()):
            worst["z_min"] = min(worst["z_min"], float(z[inside].min()))
    worst["z_min"] = round(worst["z_min"], 4)
    return worst


def _diag_row(tr, it: int, step, cfg, cam, views: list) -> dict:
    """The model's state after iteration ``it``: size, loss, scales, opacity, the network's
    offsets and gradients, what the step drew, and (past the warm-up) the near zone."""
    import torch

    from trase.losses import psnr_of_mse
    from trase.render_views import render_view

    with torch.no_grad():
        g, d = tr.gaussians, tr.deform
        s = g.scales.max(dim=1).values
        offsets = d(g.means.detach(), float(step.camera.time)) if it >= cfg.warm_up else None
        finite = all(bool(torch.isfinite(p).all()) for p in (g.means, g.sh_dc, g.sh_rest, g.log_scales, g.quats,
                                                              g.opacity_logits, *d.parameters()))
        mse = float(((step.out.color.clamp(0, 1) - step.gt) ** 2).mean())
        canonical = render_view(g, None, step.camera, step.out.color.new_zeros(3), "auto", with_deform=False)[0]
        return {
            "n": g.num_gaussians, "loss": round(float(step.loss), 5),
            "psnr": round(psnr_of_mse(mse), 2), "finite": finite,
            "scale_max": float(s.max()), "scale_p99": float(s.quantile(0.99)) if s.numel() < 16_000_000 else None,
            "large": int((s > 0.1 * tr.strategy.extent).sum()),
            "opacity_mean": round(float(g.opacities.mean()), 4),
            "d_xyz_max": None if offsets is None else float(offsets[0].abs().max()),
            "d_xyz_p99": None if offsets is None else float(offsets[0].abs().amax(dim=1).quantile(0.99)),
            "d_scale_max": None if offsets is None else float(offsets[2].max()),
            "deform_norm": round(float(sum(float(p.norm()) ** 2 for p in d.parameters()) ** 0.5), 3),
            "visible": int((step.out.radii > 0).sum()),
            "radius_max": int(step.out.radii.max()),
            "radius_over_quarter": int((step.out.radii > cam.width / 4).sum()),
            "d_scale_min": None if offsets is None else float(offsets[2].min()),
            "d_rot_max": None if offsets is None else float(offsets[1].abs().max()),
            "deform_grad": None if not step.use_deform else round(float(torch.sqrt(sum(
                (p.grad.double() ** 2).sum() for p in d.parameters() if p.grad is not None))), 6),
            "means_grad_max": None if g.means.grad is None else float(g.means.grad.abs().max()),
            "deform_lr": tr.opt_d.param_groups[0]["lr"],
            "time": round(float(step.camera.time), 4),
            "psnr_canonical": round(psnr_of_mse(float(((canonical.color.clamp(0, 1) - step.gt) ** 2).mean())), 2),
            "screen_grad_max": None if step.out.means2d.grad is None else float(
                step.out.means2d.grad.norm(dim=-1).max()),
            **(_near_zone(tr, views, cfg.near_plane) if it >= cfg.warm_up else {}),
            "near_visible": _near_visible(step),
        }


def _ceiling(model_dir: Path, scene) -> dict:
    """The saved model's label ceiling (the benchmark's ``ceiling`` stage, on the CPU)."""
    from benchmark.pipeline.context import load_geometry
    from benchmark.protocol.ceiling import label_ceiling
    from benchmark.scoring import read_mask

    g_cpu, d_cpu = load_geometry(model_dir)  # the saved model, on the CPU, as the ceiling stage loads it
    score, info = label_ceiling(g_cpu, d_cpu, scene, [read_mask(p) for p in scene.gt_masks])
    return {"miou": round(float(score.miou), 4), "object_alpha": info["object_alpha"], "objects": info["objects"]}


__all__ = ["DIAG_VARIANTS", "diagnose", "profile"]
