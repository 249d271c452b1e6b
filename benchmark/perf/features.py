"""One feature-learning step through the frozen-geometry fast path (trase.fastpath.ViewWeights:
precomputed sparse pixel -> gaussian weights) against the same step through the rasterizer
(trase.fastpath.RasterizerPath, numba backend), for Np sampled pixels and D feature channels.

A step is what trase.features.train_features does per iteration after sampling: K=16
smoothing (8 random slots), render the Np sampled pixels' features, TRASE soft-mined loss,
backward, one Adam step on the features. It is timed in two parts: the path-dependent part
(smoothing + render + backward through the render), per path and per (D, Np); and the
objective (loss forward + backward on the rendered [Np, D] features), identical for both
paths, once per Np (its cost grows as Np^2 and barely with D; above ``objective_max_pixels``
it is not run: its [Np, Np] pair matrices take ~36 B per pair, ~3.6 GB at Np = 10000, and
minutes on 2 loaded cores). Step time = sum of the two.
Both paths get the same sampled pixels and features; the rendered difference is measured
for every (D, Np), the loss difference once per Np. The precomputation (pixel weights of every
pixel inside a mask, once per view) is timed and its bytes reported; "break-even" = steps
after which the fast path has paid for it.

Scene: random gaussians in a unit ball seen from distance 3 (benchmark.perf.raster.make_scene),
40 random elliptical masks per view (~most of the image covered), M' = 25 masks per step.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from benchmark.perf.common import fmt, load_average, table, time_repeats, versions

QUICK = {"gaussians": 1_000, "width": 64, "height": 48, "n_pixels": [500], "dims": [16], "repeats": 2,
         "budget_s": 5.0, "objective_max_pixels": 5000}
DEFAULT = {"gaussians": 50_000, "width": 480, "height": 272, "n_pixels": [1000, 5000, 10000],
           "dims": [16, 32, 64, 128], "repeats": 3, "budget_s": 10.0,
           "objective_max_pixels": 5000}
N_MASKS = 40
M_PRIME = 25


def make_masks(width: int, height: int, n: int = N_MASKS, seed: int = 0):
    """A MaskSet of ``n`` random axis-aligned ellipses (areas from tiny to a third of the image)."""
    from masks.maskset import MaskSet

    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width] + 0.5
    out = np.zeros((n, height, width), bool)
    for i in range(n):
        cx, cy = rng.uniform(0, width), rng.uniform(0, height)
        rx, ry = (rng.uniform(0.03, 0.45, 2) * [width, height])
        out[i] = ((xx - cx) / rx) ** 2 + ((yy - cy) / ry) ** 2 <= 1.0
    return MaskSet.from_masks(out, generator="perf-ellipses")


def make_gaussians(n: int, width: int, height: int):
    """(GaussianModel, Camera) from the rasterizer suite's random scene."""
    from benchmark.perf.raster import make_scene
    from trase.gaussians import GaussianModel, rgb_to_sh_dc

    s, cam = make_scene(n, width, height, 3)
    op = s["opacities"].clamp(1e-4, 1 - 1e-4)
    gm = GaussianModel(s["means"], torch.log(s["scales"]), s["quats"], torch.log(op / (1 - op)),
                       rgb_to_sh_dc(s["colors"]))
    return gm, cam


def render_step(path, feats0: torch.Tensor, knn: torch.Tensor, pixels: torch.Tensor) -> Callable[[], float]:
    """The path-dependent part of a step: smoothing (8 of 16 slots) + rendering the sampled
    pixels + backward of a fixed random linear functional of the [Np, D] result."""
    from trase.smoothing import smooth_features

    feats = torch.nn.Parameter(feats0.clone())
    gen = torch.Generator().manual_seed(0)
    probe = torch.randn(pixels.shape[0], feats0.shape[1], generator=gen)

    def step() -> float:
        feats.grad = None
        rendered = path.render(0, smooth_features(feats, knn, 8, gen), pixels)  # [Np, D]
        (rendered * probe).sum().backward()
        return float(feats.grad.abs().sum())

    return step


def objective_step(objective, rendered: torch.Tensor, sample) -> Callable[[], float]:
    """The path-independent part: TRASE loss on rendered [Np, D] features, forward + backward."""
    def step() -> float:
        r = rendered.detach().clone().requires_grad_(True)
        loss = objective(r, sample)[0]
        loss.backward()
        return float(loss.detach())

    return step


def run(quick: bool = False, echo: Callable[[str], None] = print) -> dict:
    from trase.fastpath import RasterizerPath, ViewWeights
    from trase.features import build_sample, init_features
    from trase.objectives import get_objective
    from trase.smoothing import knn_indices, smooth_features

    cfg = QUICK if quick else DEFAULT
    reps = cfg["repeats"]
    n, w, h = cfg["gaussians"], cfg["width"], cfg["height"]
    echo(f"feature step, fast path vs rasterizer (numba): {n} gaussians, {w}x{h} view, {N_MASKS} masks "
         f"(M'={M_PRIME}); median of up to {reps} repeats after 1 warm-up, spread = max - min; "
         f"torch threads {torch.get_num_threads()}")
    gm, cam = make_gaussians(n, w, h)
    ms = make_masks(w, h)
    knn = knn_indices(gm.means.detach(), 16)
    objective = get_objective("trase")

    def prepare() -> ViewWeights:  # one view's weights from scratch (no disk cache)
        vw = ViewWeights(gm, None, cache_dir=None)
        vw.register(0, "perf", cam, ms.covered)
        vw.get(0)
        return vw

    prep, fast = time_repeats(prepare, 1, warmup=1)  # warm-up: numba compilation
    st = fast.stats()
    raster = RasterizerPath(gm, None, backend="numba")
    raster.register(0, "perf", cam, ms.covered)
    covered = int(ms.covered.sum())
    operators = {"prepare_seconds": prep, "bytes_per_view": st["bytes_per_view_max"],
                 "covered_pixels": covered, "bytes_per_covered_pixel": st["bytes_per_view_max"] / max(covered, 1)}
    echo(f"precomputed weights: {st['bytes_per_view_max'] / 2**20:.1f} MiB per view "
         f"({operators['bytes_per_covered_pixel']:.0f} B per covered pixel, {covered} pixels), "
         f"computed in {fmt(prep)}")

    rows, results = [], []
    objective_s: dict[int, dict] = {}
    for d in cfg["dims"]:
        feats0 = init_features(n, d, torch.Generator().manual_seed(0))
        for npix in cfg["n_pixels"]:
            sample = build_sample(ms, "random", M_PRIME, npix, np.random.default_rng(npix), view=0)
            # the same features and sample through both paths: loss and rendered difference
            first_d = npix not in objective_s
            with_objective = npix <= cfg["objective_max_pixels"]
            with torch.no_grad():
                f = smooth_features(feats0, knn, None)
                r_fast = fast.render(0, f, sample.pixels)
                r_rast = raster.render(0, f, sample.pixels)
            entry = {"dim": d, "n_pixels_target": npix, "n_pixels": int(sample.pixels.shape[0]),
                     "max_abs_rendered_diff": float((r_fast - r_rast).abs().max()) if r_fast.numel() else 0.0}
            if first_d and with_objective:  # the loss (Np^2 pairs) once per Np
                with torch.no_grad():
                    l_fast = float(objective(r_fast, sample)[0])
                    l_rast = float(objective(r_rast, sample)[0])
                entry.update(loss_fast=l_fast, loss_raster=l_rast, loss_abs_diff=abs(l_fast - l_rast))
            for name, path in (("fastpath", fast), ("rasterizer", raster)):
                t, _ = time_repeats(render_step(path, feats0, knn, sample.pixels), reps, warmup=1,
                                    budget_s=cfg["budget_s"])
                entry[f"{name}_render_s"] = t
            if first_d:
                objective_s[npix] = (time_repeats(objective_step(objective, r_fast, sample), reps,
                                                  budget_s=cfg["budget_s"])[0] if with_objective else None)
            t_obj = entry["objective_s"] = objective_s[npix]
            fr, rr = entry["fastpath_render_s"]["median"], entry["rasterizer_render_s"]["median"]
            entry["render_speedup"] = rr / max(fr, 1e-12)
            if t_obj is not None:
                ob = t_obj["median"]
                entry["step_fastpath_s"] = fr + ob  # smoothing + render + loss + backward (Adam: negligible)
                entry["step_rasterizer_s"] = rr + ob
                entry["step_speedup"] = (rr + ob) / max(fr + ob, 1e-12)
            gain = rr - fr
            entry["break_even_steps"] = math.ceil(prep["median"] / gain) if gain > 0 else None
            results.append(entry)
            rows.append([f"D={d} Np={npix}", fmt(entry["fastpath_render_s"]), fmt(entry["rasterizer_render_s"]),
                         f"{entry['render_speedup']:.1f}x", fmt(t_obj) if t_obj else "not run",
                         f"{entry['step_speedup']:.2f}x" if t_obj else "-",
                         f"{entry['loss_abs_diff']:.1e}" if "loss_abs_diff" in entry else "-",
                         f"{entry['max_abs_rendered_diff']:.1e}",
                         str(entry["break_even_steps"])])
    # thread sensitivity: the fast-path step (render + objective) at the smallest setting with
    # torch on 1 and 2 threads and the current count (on shared, loaded cores threads can thrash)
    d0, n0 = cfg["dims"][0], cfg["n_pixels"][0]
    sample = build_sample(ms, "random", M_PRIME, n0, np.random.default_rng(n0), view=0)
    feats0 = init_features(n, d0, torch.Generator().manual_seed(0))
    with torch.no_grad():
        r0 = fast.render(0, smooth_features(feats0, knn, None), sample.pixels)
    threads = {}
    default_threads = torch.get_num_threads()
    for nt in sorted({1, 2, default_threads}):
        torch.set_num_threads(nt)
        try:
            tr, _ = time_repeats(render_step(fast, feats0, knn, sample.pixels), reps, warmup=1, budget_s=cfg["budget_s"])
            to, _ = time_repeats(objective_step(objective, r0, sample), reps, warmup=1, budget_s=cfg["budget_s"])
        finally:
            torch.set_num_threads(default_threads)
        threads[str(nt)] = {"render_s": tr, "objective_s": to}
        rows.append([f"D={d0} Np={n0} torch threads={nt}", fmt(tr), "", "", fmt(to), "", "", "", ""])
    echo(table(rows, ["setting", "fast path render", "rasterizer render", "render x", "objective",
                      "step x", "|loss diff|", "max |render diff|", "break-even"]))
    echo("render = smoothing + render of the Np pixels + backward; objective = TRASE loss forward + backward "
         "(the same for both paths); step x = (rasterizer render + objective) / (fast render + objective)")
    return {
        "description": __doc__.strip().splitlines()[0],
        "quick": quick,
        "settings": {**cfg, "masks": N_MASKS, "m_prime": M_PRIME, "objective": "trase", "knn": 16, "knn_keep": 8,
                     "torch_threads": torch.get_num_threads()},
        "versions": versions("torch", "numba", "numpy"),
        "operators": operators,
        "steps": results,
        "threads": threads,
        "load_average_end": load_average(),
    }
