"""One reconstruction iteration and one feature step at the paper's settings on a CUDA GPU
(gsplat rasterizer), and the frozen-geometry fast path against rasterizing every step there.

Random scenes of the sizes the paper's runs reach (gaussians in a unit ball, a 960x536 view as
HyperNeRF's 2x images): a reconstruction iteration is the 8x256 deformation network (its output
layers zeroed, so the offsets are as small as a trained network's) over every gaussian, a colour
render, L1 + D-SSIM, backward and both Adam steps; a feature step is the
32-d features smoothed over 8 of 16 neighbours, rendered at Np = 5000 sampled pixels with
M = 25 random masks, the soft-mined objective, backward and Adam. Wall-clock medians after
warm-up, each step closed by a device synchronisation; peak GPU memory per setting. The fast
path's per-view weights are computed on the CPU (numba), timed separately.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np
import torch

from benchmark.perf.raster import make_scene

QUICK = [(100_000, 960, 536)]
DEFAULT = [(100_000, 960, 536), (300_000, 960, 536)]


class PerfGpuError(RuntimeError):
    user_facing = True


def _timed(step: Callable[[], None], repeats: int, warmup: int) -> dict:
    for _ in range(warmup):
        step()
    torch.cuda.synchronize()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        step()
        torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return {"median_ms": 1e3 * statistics.median(times), "spread_ms": 1e3 * (max(times) - min(times))}


def reconstruction_step(n: int, width: int, height: int, repeats: int) -> dict:
    from trase.deformation import DeformMLP, deformed
    from trase.gaussians import GaussianModel
    from trase.losses import l1_loss, ssim
    from trase.reconstruct import ReconstructionConfig
    from trase.render import rasterize
    from trase.trainer import make_optimizers

    sc, cam = make_scene(n, width, height, 0)
    g = GaussianModel.from_points(sc["means"].numpy(), sc["colors"].numpy(), sh_degree=3).cuda()
    g.active_sh_degree = 3  # every SH band, as late in training
    # zero heads: the offsets of a network that has trained (a few hundredths of a unit). With
    # PyTorch's initialisation they are ~0.1-0.5 units, every gaussian then covers hundreds of
    # tiles, and the steps change that: on an H100, 25 of ~45 ms went to gsplat's tile
    # intersection and sort, and medians drifted between 27 and 48 ms from one call to the next
    deform = DeformMLP.preset("paper").zero_heads().cuda()
    opt_g, opt_d = make_optimizers(g, deform, ReconstructionConfig.paper())
    gt = torch.rand(height, width, 3, device="cuda")
    bg = torch.zeros(3, device="cuda")

    def step():
        m, q, s = deformed(g, deform, 0.5)
        out = rasterize(m, q, s, g.opacities, cam, colors=g.sh_for_render(), sh_degree=3, background=bg)
        loss = 0.8 * l1_loss(out.color, gt) + 0.2 * (1.0 - ssim(out.color, gt))
        loss.backward()
        opt_g.step()
        opt_d.step()
        opt_g.zero_grad(set_to_none=True)
        opt_d.zero_grad(set_to_none=True)

    torch.cuda.reset_peak_memory_stats()
    t = _timed(step, repeats, warmup=3)
    return t | {"peak_gpu_mib": torch.cuda.max_memory_allocated() / 2**20}


def feature_steps(n: int, width: int, height: int, repeats: int) -> dict:
    from trase.features import FeatureConfig, render_ready
    from trase.objectives import PixelSample, get_objective
    from trase.render import pixel_weights, rasterize
    from trase.smoothing import knn_indices

    sc, cam = make_scene(n, width, height, 0)
    geo = [sc[k].cuda() for k in ("means", "quats", "scales", "opacities")]
    cfg = FeatureConfig.preset("paper")
    rng = np.random.default_rng(0)
    gen = torch.Generator().manual_seed(0)
    knn = knn_indices(sc["means"], cfg.knn).cuda()
    feats = torch.nn.Parameter(torch.rand(n, cfg.dim, device="cuda"))
    opt = torch.optim.Adam([feats], lr=cfg.lr, eps=cfg.eps)
    objective = get_objective(cfg.objective)
    hw = width * height
    pix = torch.from_numpy(rng.choice(hw, cfg.n_pixels, replace=False))
    M = int(cfg.n_masks)
    member = torch.from_numpy(rng.random((cfg.n_pixels, M)) < 0.15)
    sample = PixelSample(pixels=pix, membership=member, mask_area=member.sum(0).float() * hw / cfg.n_pixels,
                         pixel_mean_area=torch.full((cfg.n_pixels,), hw / 10.0)).to("cuda")
    out = {}

    def run(render):
        def step():
            f = render_ready(feats, knn, cfg, gen)
            loss, _ = objective(render(f), sample)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        return step

    def by_rasterizer(f):
        img = rasterize(*geo, cam, features=f).features.reshape(-1, f.shape[1])
        return img[sample.pixels]

    torch.cuda.reset_peak_memory_stats()
    out["rasterizer"] = _timed(run(by_rasterizer), repeats, warmup=3) | {
        "peak_gpu_mib": torch.cuda.max_memory_allocated() / 2**20}
    try:
        from trase.fastpath import render_rows

        t0 = time.perf_counter()
        pw = pixel_weights(*geo, cam)  # every pixel, on the CPU, returned on the GPU
        prep = time.perf_counter() - t0
        rows = sample.pixels  # all pixels registered: row = pixel id

        torch.cuda.reset_peak_memory_stats()
        out["fastpath"] = _timed(run(lambda f: render_rows(pw, rows, f)), repeats, warmup=3) | {
            "peak_gpu_mib": torch.cuda.max_memory_allocated() / 2**20, "weights_s": prep,
            "entries": int(pw.indices.numel())}
    except Exception as exc:  # noqa: BLE001 - the CPU weights need numba; report what broke
        out["fastpath"] = {"error": f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"}
    return out


def unavailable() -> str | None:
    """Why this suite cannot run on this machine, or None (``trase-bench perf`` with no suite
    named skips it then; named, it is an error)."""
    from trase.devices import gsplat_missing

    if not torch.cuda.is_available():
        return "torch sees no CUDA GPU here"
    return gsplat_missing("cuda")


def run(quick: bool = False, echo: Callable[[str], None] = print) -> dict:
    why = unavailable()
    if why:
        raise PerfGpuError(f"perf gpu: {why}")
    settings = QUICK if quick else DEFAULT
    repeats = 10 if quick else 30
    device = torch.cuda.get_device_name()
    echo(f"GPU: {device}; medians of {repeats} steps after 3 warm-ups")
    rows = []
    for n, w, h in settings:
        label = f"{n // 1000}k gaussians {w}x{h}"
        rec = reconstruction_step(n, w, h, repeats)
        echo(f"{label}: reconstruction iteration {rec['median_ms']:.1f} ms (+-{rec['spread_ms'] / 2:.1f}), "
             f"peak {rec['peak_gpu_mib']:.0f} MiB")
        feat = feature_steps(n, w, h, repeats)
        r = feat["rasterizer"]
        echo(f"{label}: feature step, rasterizing {r['median_ms']:.1f} ms (+-{r['spread_ms'] / 2:.1f}), "
             f"peak {r['peak_gpu_mib']:.0f} MiB")
        fp = feat["fastpath"]
        if "error" in fp:
            echo(f"{label}: feature step, fast path failed: {fp['error']}")
        else:
            echo(f"{label}: feature step, fast path {fp['median_ms']:.1f} ms (+-{fp['spread_ms'] / 2:.1f}), "
                 f"peak {fp['peak_gpu_mib']:.0f} MiB; weights of the view {fp['weights_s']:.2f} s on the CPU "
                 f"({fp['entries'] / 1e6:.1f} M entries)")
        rows.append({"gaussians": n, "width": w, "height": h, "reconstruction": rec, "features": feat})
    return {"description": __doc__.strip().splitlines()[0], "quick": quick, "gpu": device,
            "repeats": repeats, "settings": rows}
