"""One feature-learning step through the frozen-geometry fast path (trase.fastpath.ViewWeights:
precomputed sparse pixel -> gaussian weights) against the same step through the rasterizer
(trase.fastpath.RasterizerPath, numba backend), and the objective both paths share.

Three parts (and a real-scale row of part 1), side by side in one run:

1. Whole step on the default synthetic scene (the target: Np = 5000, synthetic NeRF-DS,
   ground-truth geometry, synthetic masks, the dataset's M'; ``--quick``: the random scene of
   part 3). A step is what trase.features.train_features does per iteration after sampling:
   smoothing (8 of K=16 slots) -> render the Np sampled pixels -> TRASE soft-mined loss ->
   backward. Timed whole through each path, plus its parts: render + backward from a leaf (R
   rasterizer, F fast path), smoothing forward + backward (X) and the objective forward +
   backward (O fused, O_ref the dense torch reference). X and O are the same for both paths, so
   the step ratio is about (R + O + X) / (F + O + X); "O for 10x" = (R - 10 F - 9 X) / 9 is the
   objective time a 10x step would need. The loss of the two paths and of the two objective
   implementations is compared. Repeated at 1 and 2 threads (``step_threads``).
1b. The same whole step at real-data scale: the random scene of part 3 with 100k gaussians at
   960x536 (the HyperNeRF benchmark resolution), 40 random elliptical masks (M' = 25), Np = 5000,
   first thread count only. "ceiling" = (R + X) / (F + X) is the step ratio with a free objective.
2. The objective alone at Np = 5000 and 10000 (D = 32 rendered features, M' = 25 of 40 random
   elliptical masks): fused kernels vs dense reference, |loss diff|, max relative gradient diff.
3. Render grid (D x Np) on a random scene (gaussians in a unit ball seen from distance 3,
   benchmark.perf.raster.make_scene; 40 random elliptical masks, M' = 25): the path-dependent
   part (smoothing + render + backward) per path, the fused objective per Np, step ratio; the
   precomputation (pixel weights of every pixel inside a mask, once per view) is timed, its bytes
   reported; "break-even" = steps after which the fast path has paid for it.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable

import numpy as np
import torch

from benchmark.perf.common import fmt, load_average, table, time_repeats, versions
from benchmark.perf.feature_scenes import N_MASKS, make_gaussians, make_masks, synthetic_view
from benchmark.perf.feature_step import (
    M_PRIME,
    STEP_DIM,
    compare_objectives,
    objective_step,
    render_step,
    whole_step,
)

QUICK = {"gaussians": 1_000, "width": 64, "height": 48, "n_pixels": [500], "dims": [16], "repeats": 2,
         "budget_s": 5.0, "objective_pixels": [500], "step_pixels": 500, "step_threads": [1],
         "synthetic": None, "real_scale": {"gaussians": 2_000, "width": 96, "height": 54, "label": "quick stand-in"}}
DEFAULT = {"gaussians": 50_000, "width": 480, "height": 272, "n_pixels": [1000, 5000, 10000],
           "dims": [16, 32, 64, 128], "repeats": 5, "budget_s": 10.0, "objective_pixels": [5000, 10000],
           "step_pixels": 5000, "step_threads": [1, 2], "synthetic": {"dataset": "nerfds", "size": "small"},
           "real_scale": {"gaussians": 100_000, "width": 960, "height": 536,
                          "label": "HyperNeRF benchmark resolution"}}
def objective_alone(fast, gm, ms, knn, n_pixels: list[int], reps: int, budget_s: float, echo) -> list[dict]:
    """Part 2: fused vs dense reference objective on the same rendered features, and the fused
    one with the soft correspondence (the cpu preset's on small monocular images)."""
    from trase.features import build_sample, init_features
    from trase.objectives import get_objective
    from trase.smoothing import smooth_features

    fused, reference = get_objective("trase", impl="fused"), get_objective("trase", impl="reference")
    soft = get_objective("trase", impl="fused", correspondence="jaccard")
    soft_reference = get_objective("trase", impl="reference", correspondence="jaccard")
    feats = init_features(gm.num_gaussians, STEP_DIM, torch.Generator().manual_seed(0))
    with torch.no_grad():
        smoothed = smooth_features(feats, knn, None)
    out, rows = [], []
    for npix in n_pixels:
        sample = build_sample(ms, "random", M_PRIME, npix, np.random.default_rng(npix), view=0)
        with torch.no_grad():
            rendered = fast.render(0, smoothed, sample.pixels)
        tf, rf = time_repeats(objective_step(fused, rendered, sample), reps, warmup=1, budget_s=budget_s)
        tr, rr = time_repeats(objective_step(reference, rendered, sample), reps, warmup=1, budget_s=budget_s)
        tj, rj = time_repeats(objective_step(soft, rendered, sample), reps, warmup=1, budget_s=budget_s)
        soft_diff = compare_objectives(rj, objective_step(soft_reference, rendered, sample)())
        e = {"n_pixels": sample.n_pixels, "n_valid": int(sample.membership.any(1).sum()), "fused_s": tf,
             "reference_s": tr, "speedup": tr["median"] / max(tf["median"], 1e-12), "fused_jaccard_s": tj,
             "jaccard_vs_reference": soft_diff, **compare_objectives(rf, rr)}
        out.append(e)
        rows.append([f"Np={e['n_pixels']} V={e['n_valid']}", fmt(tf), fmt(tr), f"{e['speedup']:.1f}x", fmt(tj),
                     f"{e['loss_abs_diff']:.1e}", f"{e['grad_max_rel_diff']:.1e}", str(e["stats_equal"])])
    echo(table(rows, ["objective alone (D=32)", "fused", "dense reference", "speed-up", "fused, soft C",
                      "|loss diff|", "max rel grad diff", "stats equal"]))
    return out


def _whole_steps(cfg: dict, gm, cam, ms, reps: int, echo) -> tuple[dict, dict, list[int]]:
    """Parts 1 and 1b: the whole step on the default scene (quick: the random scene of part 3) at
    each thread count, and at real-data scale at the first -> (part 1, part 1b, thread counts)."""
    if cfg["synthetic"]:
        scene = synthetic_view(**cfg["synthetic"])
    else:
        scene = {"name": "random scene (part 3)", "gaussians": gm, "deformation": None, "camera": cam,
                 "masks": ms, "m_prime": M_PRIME}
    # thread counts up to this run's (`trase-bench perf --threads 1` runs one row only)
    step_threads = [t for t in cfg["step_threads"] if t <= torch.get_num_threads()] or [1]
    step = whole_step(scene, cfg["step_pixels"], reps, cfg["budget_s"], step_threads, echo)

    # 1b. the same step at real-data scale (random geometry, HyperNeRF benchmark resolution)
    rs = cfg["real_scale"]
    gm_r, cam_r = make_gaussians(rs["gaussians"], rs["width"], rs["height"])
    real_scene = {"name": f"random scene {rs['gaussians'] // 1000}k gaussians {rs['width']}x{rs['height']} "
                          f"({rs['label']}), {N_MASKS} random elliptical masks",
                  "gaussians": gm_r, "deformation": None, "camera": cam_r, "masks": make_masks(rs["width"], rs["height"]),
                  "m_prime": M_PRIME}
    step_real = whole_step(real_scene, cfg["step_pixels"], reps, cfg["budget_s"], step_threads[:1], echo)
    del gm_r, real_scene
    return step, step_real, step_threads


def _prepare_weights(gm, cam, ms):
    """One view's fast-path weights from scratch (no disk cache), timed after a warm-up that
    compiles the numba kernels -> (stats, the ViewWeights)."""
    from trase.fastpath import ViewWeights

    def prepare() -> ViewWeights:
        vw = ViewWeights(gm, None, cache_dir=None)
        vw.register(0, "perf", cam, ms.covered)
        vw.get(0)
        return vw

    return time_repeats(prepare, 1, warmup=1)  # warm-up: numba compilation


def _operators(fast, ms, prep: dict) -> dict:
    """The precomputation's cost: seconds and bytes per view, bytes per covered pixel."""
    st = fast.stats()
    covered = int(ms.covered.sum())
    return {"prepare_seconds": prep, "bytes_per_view": st["bytes_per_view_max"],
            "covered_pixels": covered, "bytes_per_covered_pixel": st["bytes_per_view_max"] / max(covered, 1)}


def _grid_agreement(d: int, npix: int, feats0: torch.Tensor, knn: torch.Tensor, sample, fast, raster,
                    objective, with_loss: bool) -> tuple[dict, torch.Tensor]:
    """The same features [N, D] and sample through both paths: the rendered [Np, D] difference
    and (``with_loss``: once per Np, the loss has Np^2 pairs) both losses -> (entry, fast render)."""
    from trase.smoothing import smooth_features

    with torch.no_grad():
        f = smooth_features(feats0, knn, None)
        r_fast = fast.render(0, f, sample.pixels)
        r_rast = raster.render(0, f, sample.pixels)
    entry = {"dim": d, "n_pixels_target": npix, "n_pixels": int(sample.pixels.shape[0]),
             "max_abs_rendered_diff": float((r_fast - r_rast).abs().max()) if r_fast.numel() else 0.0}
    if with_loss:
        with torch.no_grad():
            l_fast = float(objective(r_fast, sample)[0])
            l_rast = float(objective(r_rast, sample)[0])
        entry.update(loss_fast=l_fast, loss_raster=l_rast, loss_abs_diff=abs(l_fast - l_rast))
    return entry, r_fast


def _add_step_figures(entry: dict, t_obj: dict, prep: dict) -> None:
    """Step times and speed-ups from the render timings and the (shared) objective timing, and
    the steps after which the fast path's precomputation has paid for itself."""
    entry["objective_s"] = t_obj
    fr, rr = entry["fastpath_render_s"]["median"], entry["rasterizer_render_s"]["median"]
    ob = t_obj["median"]
    entry["render_speedup"] = rr / max(fr, 1e-12)
    entry["step_fastpath_s"] = fr + ob  # smoothing + render + loss + backward (Adam: negligible)
    entry["step_rasterizer_s"] = rr + ob
    entry["step_speedup"] = (rr + ob) / max(fr + ob, 1e-12)
    gain = rr - fr
    entry["break_even_steps"] = math.ceil(prep["median"] / gain) if gain > 0 else None


def _grid_row(d: int, npix: int, entry: dict, t_obj: dict) -> list[str]:
    """One (D, Np) row of the render grid table."""
    return [f"D={d} Np={npix}", fmt(entry["fastpath_render_s"]), fmt(entry["rasterizer_render_s"]),
            f"{entry['render_speedup']:.1f}x", fmt(t_obj), f"{entry['step_speedup']:.2f}x",
            f"{entry['loss_abs_diff']:.1e}" if "loss_abs_diff" in entry else "-",
            f"{entry['max_abs_rendered_diff']:.1e}", str(entry["break_even_steps"])]


def _render_grid(cfg: dict, gm, cam, ms, knn: torch.Tensor, objective, fast, prep: dict, operators: dict,
                 reps: int, echo) -> list[dict]:
    """Part 3: the path-dependent part of a step per (D, Np) through each path, the fused
    objective once per Np -> one entry per (D, Np)."""
    from trase.fastpath import RasterizerPath
    from trase.features import build_sample, init_features

    n, w, h = cfg["gaussians"], cfg["width"], cfg["height"]
    echo(f"render grid: random scene, {n} gaussians, {w}x{h} view, {N_MASKS} masks (M'={M_PRIME})")
    raster = RasterizerPath(gm, None, backend="numba")
    raster.register(0, "perf", cam, ms.covered)
    echo(f"precomputed weights: {operators['bytes_per_view'] / 2**20:.1f} MiB per view "
         f"({operators['bytes_per_covered_pixel']:.0f} B per covered pixel, {operators['covered_pixels']} pixels), "
         f"computed in {fmt(prep)}")
    rows, results = [], []
    objective_s: dict[int, dict] = {}
    for d in cfg["dims"]:
        feats0 = init_features(n, d, torch.Generator().manual_seed(0))
        for npix in cfg["n_pixels"]:
            sample = build_sample(ms, "random", M_PRIME, npix, np.random.default_rng(npix), view=0)
            first_d = npix not in objective_s
            entry, r_fast = _grid_agreement(d, npix, feats0, knn, sample, fast, raster, objective, first_d)
            for name, path in (("fastpath", fast), ("rasterizer", raster)):
                t, _ = time_repeats(render_step(path, feats0, knn, sample.pixels), reps, warmup=1,
                                    budget_s=cfg["budget_s"])
                entry[f"{name}_render_s"] = t
            if first_d:
                objective_s[npix] = time_repeats(objective_step(objective, r_fast, sample), reps, warmup=1,
                                                 budget_s=cfg["budget_s"])[0]
            _add_step_figures(entry, objective_s[npix], prep)
            results.append(entry)
            rows.append(_grid_row(d, npix, entry, objective_s[npix]))
    echo(table(rows, ["setting", "fast path render", "rasterizer render", "render x", "objective (fused)",
                      "step x", "|loss diff|", "max |render diff|", "break-even"]))
    echo("render = smoothing + render of the Np pixels + backward; objective = TRASE loss forward + backward "
         "(the same for both paths); step x = (rasterizer render + objective) / (fast render + objective)")
    return results


def run(quick: bool = False, echo: Callable[[str], None] = print) -> dict:
    """The suite: parts 1, 1b, 2 and 3 (see the module docs) -> every figure, JSON-ready."""
    from trase.objectives import get_objective
    from trase.smoothing import knn_indices

    cfg = QUICK if quick else DEFAULT
    reps = cfg["repeats"]
    n, w, h = cfg["gaussians"], cfg["width"], cfg["height"]
    echo(f"feature step, fast path vs rasterizer (numba); median of up to {reps} repeats after 1 warm-up, "
         f"spread = max - min; torch threads {torch.get_num_threads()}")
    gm, cam = make_gaussians(n, w, h)
    ms = make_masks(w, h)
    knn = knn_indices(gm.means.detach(), 16)
    objective = get_objective("trase")
    step, step_real, step_threads = _whole_steps(cfg, gm, cam, ms, reps, echo)  # 1 and 1b
    prep, fast = _prepare_weights(gm, cam, ms)
    operators = _operators(fast, ms, prep)
    objective_cmp = objective_alone(fast, gm, ms, knn, cfg["objective_pixels"], reps, cfg["budget_s"], echo)  # 2
    results = _render_grid(cfg, gm, cam, ms, knn, objective, fast, prep, operators, reps, echo)  # 3
    t1 = step["threads"][str(step_threads[0])]
    tr = step_real["threads"][str(step_threads[0])]
    summary = {"step_speedup": t1["step_speedup"], "ratio_bound": t1["ratio_bound"],
               "real_scale_step_speedup": tr["step_speedup"], "real_scale_ratio_bound": tr["ratio_bound"],
               "objective_speedup_vs_dense": statistics.median(e["speedup"] for e in objective_cmp)}
    return {
        "description": __doc__.strip().splitlines()[0],
        "quick": quick,
        "settings": {**{k: v for k, v in cfg.items()}, "masks": N_MASKS, "m_prime": M_PRIME, "objective": "trase",
                     "knn": 16, "knn_keep": 8, "torch_threads": torch.get_num_threads()},
        "versions": versions("torch", "numba", "numpy"),
        "whole_step": step,
        "whole_step_real_scale": step_real,
        "objective_alone": objective_cmp,
        "operators": operators,
        "steps": results,
        "summary": summary,
        "load_average_end": load_average(),
    }
