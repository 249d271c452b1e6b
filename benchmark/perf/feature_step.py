"""The whole feature-learning step of ``trase-bench perf features`` (its part 1): smoothing ->
render of the sampled pixels -> TRASE soft-mined loss -> backward, timed whole through the
frozen-geometry fast path and through the rasterizer, and by its parts (render + backward,
smoothing, the fused and the reference objective), at each thread count."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import torch

from benchmark.perf.common import fmt, table, time_repeats

M_PRIME = 25
STEP_DIM = 32  # the paper's feature dimension


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


def objective_step(objective, rendered: torch.Tensor, sample) -> Callable[[], tuple]:
    """The path-independent part: the loss on rendered [Np, D] features, forward + backward.
    Returns (loss, stats, gradient) of the last call."""
    def step():
        r = rendered.detach().clone().requires_grad_(True)
        loss, stats = objective(r, sample)
        loss.backward()
        return float(loss.detach()), stats, r.grad

    return step


def compare_objectives(fused: tuple, ref: tuple) -> dict:
    """(loss, stats, grad) of the fused and the reference objective -> their differences."""
    gf, gr = fused[2], ref[2]
    scale = float(gr.abs().max()) if gr.numel() else 0.0
    return {"loss_abs_diff": abs(fused[0] - ref[0]),
            "grad_max_rel_diff": float((gf - gr).abs().max()) / scale if scale > 0 else 0.0,
            "stats_equal": all(fused[1][k] == ref[1][k] for k in ("n_pos", "n_neg", "n_valid"))}


class _threads:
    """Torch and numba on ``n`` threads inside the block (numba's pool capped), restored after."""

    def __init__(self, n: int) -> None:
        self.n = n

    def __enter__(self):
        import numba

        self.old = (torch.get_num_threads(), numba.get_num_threads())
        numba.set_num_threads(min(self.n, numba.config.NUMBA_NUM_THREADS))
        torch.set_num_threads(self.n)  # after numba: they share the OpenMP runtime
        return self

    def __exit__(self, *exc):
        import numba

        numba.set_num_threads(self.old[1])
        torch.set_num_threads(self.old[0])


@dataclasses.dataclass
class _StepSetup:
    """One view of a scene ready for part 1: the sample, the features and both paths, shared by
    every timed part so that the two paths and the two objectives see the same inputs."""

    sample: object  # PixelSample of Np pixels and M' masks
    feats0: torch.Tensor  # [N, D] initial features
    slots: torch.Tensor  # [N, 8] the same 8 of the K=16 neighbour slots for both paths
    fused: object  # the TRASE objective, fused kernels
    reference: object  # the TRASE objective, dense torch reference
    fast: object  # ViewWeights, the view's weights computed
    raster: object  # RasterizerPath (numba)
    prep: dict  # time_repeats stats of computing the fast path's weights
    smoothed: torch.Tensor  # [N, D] feats0 smoothed over the slots (no grad)
    rendered: torch.Tensor  # [Np, D] smoothed through the fast path (no grad)
    feat_diff: float  # max |fast - rasterizer| of the rendered features


def _prepare_step(scene: dict, n_pixels: int) -> _StepSetup:
    """The sample, features, slots, objectives and both paths of ``scene``'s view; the fast
    path's weights are computed (and timed) once here."""
    from trase.fastpath import RasterizerPath, ViewWeights
    from trase.features import build_sample, init_features
    from trase.objectives import get_objective
    from trase.smoothing import knn_indices, smooth_features

    gm, deform, cam, ms = scene["gaussians"], scene["deformation"], scene["camera"], scene["masks"]
    sample = build_sample(ms, "random", scene["m_prime"], n_pixels, np.random.default_rng(0), view=0)
    gen = torch.Generator().manual_seed(0)
    feats0 = init_features(gm.num_gaussians, STEP_DIM, gen)
    knn = knn_indices(gm.means.detach(), 16)
    slots = knn[:, torch.randperm(16, generator=gen)[:8]]  # the same 8 slots for both paths
    fused, reference = get_objective("trase", impl="fused"), get_objective("trase", impl="reference")
    fast = ViewWeights(gm, deform, cache_dir=None)
    raster = RasterizerPath(gm, deform, backend="numba")
    for p in (fast, raster):
        p.register(0, "perf", cam, ms.covered)
    prep, _ = time_repeats(lambda: fast.get(0), 1)
    with torch.no_grad():
        smoothed = smooth_features(feats0, slots, None)
        rendered = fast.render(0, smoothed, sample.pixels)  # [Np, D]
        feat_diff = float((rendered - raster.render(0, smoothed, sample.pixels)).abs().max())
    return _StepSetup(sample, feats0, slots, fused, reference, fast, raster, prep, smoothed, rendered, feat_diff)


def _step_parts(s: _StepSetup) -> tuple[tuple[str, Callable], ...]:
    """(name, callable) of each timed part of part 1: the whole step through each path, render +
    backward from a leaf through each path, smoothing, and both objectives."""
    from trase.smoothing import smooth_features

    def step(path):
        def run():
            f = torch.nn.Parameter(s.feats0.clone())
            loss, _ = s.fused(path.render(0, smooth_features(f, s.slots, None), s.sample.pixels), s.sample)
            loss.backward()
            return float(loss.detach())
        return run

    def render_backward(path):
        def run():
            leaf = s.smoothed.clone().requires_grad_(True)
            r = path.render(0, leaf, s.sample.pixels)
            r.backward(torch.ones_like(r))
        return run

    def smoothing():  # path-independent too: the third part of both steps
        f = torch.nn.Parameter(s.feats0.clone())
        sm = smooth_features(f, s.slots, None)
        sm.backward(torch.ones_like(sm))

    return (("step_fast", step(s.fast)), ("step_raster", step(s.raster)),
            ("render_fast", render_backward(s.fast)), ("render_raster", render_backward(s.raster)),
            ("smoothing", smoothing),
            ("objective", objective_step(s.fused, s.rendered, s.sample)),
            ("objective_reference", objective_step(s.reference, s.rendered, s.sample)))


def _step_entry(t: dict) -> dict:
    """Timings of the parts (``name`` -> stats, ``name_result`` -> last result) -> one thread
    count's entry: the timings, the two paths' losses and the ratio arithmetic."""
    m = {k: v["median"] for k, v in t.items() if not k.endswith("_result")}
    R, F, O, Oref = m["render_raster"], m["render_fast"], m["objective"], m["objective_reference"]
    X = m["smoothing"]
    entry = {k: v for k, v in t.items() if not k.endswith("_result")}
    entry.update(
        loss_fast=t["step_fast_result"], loss_raster=t["step_raster_result"],
        loss_abs_diff=abs(t["step_fast_result"] - t["step_raster_result"]),
        objective_vs_reference=compare_objectives(t["objective_result"], t["objective_reference_result"]),
        step_speedup=m["step_raster"] / max(m["step_fast"], 1e-12),
        render_speedup=R / max(F, 1e-12),
        ratio_bound=(R + O + X) / max(F + O + X, 1e-12),
        ratio_bound_reference_objective=(R + Oref + X) / max(F + Oref + X, 1e-12),
        objective_for_10x_s=(R - 10 * F - 9 * X) / 9,
        ceiling_free_objective=(R + X) / max(F + X, 1e-12),
    )
    return entry


STEP_HEADERS = ["", "raster step", "fast step", "step x", "R raster render", "F fast render", "R/F",
                "X smoothing", "O objective", "O_ref (dense)", "(R+O+X)/(F+O+X)", "O for 10x", "|loss diff|"]


def _step_row(nt: int, t: dict, entry: dict) -> list[str]:
    """One thread count's row of the part 1 table."""
    return [f"threads={nt}", fmt(t["step_raster"]), fmt(t["step_fast"]), f"{entry['step_speedup']:.2f}x",
            fmt(t["render_raster"]), fmt(t["render_fast"]), f"{entry['render_speedup']:.1f}x",
            fmt(t["smoothing"]), fmt(t["objective"]), fmt(t["objective_reference"]),
            f"{entry['ratio_bound']:.2f}x",
            f"{entry['objective_for_10x_s'] * 1e3:.1f}ms", f"{entry['loss_abs_diff']:.1e}"]


def _echo_step_notes(out: dict, echo) -> None:
    """The lines under the part 1 table: objective agreement, the bound's arithmetic per thread
    count, and what the letters mean."""
    for nt, e in out["threads"].items():
        c = e["objective_vs_reference"]
        echo(f"threads={nt}: fused vs dense objective on the same features: |loss diff| {c['loss_abs_diff']:.1e}, "
             f"max rel grad diff {c['grad_max_rel_diff']:.1e}, n_pos/n_neg/n_valid equal: {c['stats_equal']}")
    for nt, e in out["threads"].items():
        m = {k: e[k]["median"] * 1e3 for k in ("render_raster", "render_fast", "smoothing", "objective")}
        echo(f"threads={nt}: bound (R+O+X)/(F+O+X) = ({m['render_raster']:.1f}+{m['objective']:.1f}+"
             f"{m['smoothing']:.1f})/({m['render_fast']:.1f}+{m['objective']:.1f}+{m['smoothing']:.1f}) ms = "
             f"{e['ratio_bound']:.2f}x; ceiling with O = 0: (R+X)/(F+X) = {e['ceiling_free_objective']:.2f}x; "
             f"rendered feature max |diff| {out['feature_max_abs_diff']:.1e}")
    echo("step = smoothing + render + objective + backward; R, F = render + backward from a leaf; X = smoothing "
         "forward + backward; O = objective forward + backward; X and O are the same for both paths, so a 10x "
         "step needs O <= (R - 10 F - 9 X) / 9 (negative: impossible even with O = 0)")


def whole_step(scene: dict, n_pixels: int, reps: int, budget_s: float, threads: list[int], echo) -> dict:
    """Part 1: the whole step through both paths, its parts, and the ratio arithmetic."""
    s = _prepare_step(scene, n_pixels)
    gm, cam, sample = scene["gaussians"], scene["camera"], s.sample
    out = {"scene": scene["name"], "n_gaussians": gm.num_gaussians, "image": f"{cam.width}x{cam.height}",
           "n_pixels": sample.n_pixels, "n_valid": int(sample.membership.any(1).sum()), "m_prime": sample.n_masks,
           "dim": STEP_DIM, "precompute_s": s.prep, "bytes_per_view": s.fast.stats()["bytes_per_view_max"],
           "feature_max_abs_diff": s.feat_diff, "threads": {}}
    echo(f"whole step: {out['scene']}; {out['n_gaussians']} gaussians, {out['image']}, Np={out['n_pixels']} "
         f"(V={out['n_valid']} in a sampled mask), M'={out['m_prime']}, D={STEP_DIM}; pixel weights "
         f"{out['bytes_per_view'] / 2**20:.1f} MiB, computed in {fmt(s.prep)}")
    rows = []
    for nt in threads:
        with _threads(nt):
            t = {}
            for name, fn in _step_parts(s):
                t[name], t[name + "_result"] = time_repeats(fn, reps, warmup=1, budget_s=budget_s)
        entry = out["threads"][str(nt)] = _step_entry(t)
        rows.append(_step_row(nt, t, entry))
    echo(table(rows, STEP_HEADERS))
    _echo_step_notes(out, echo)
    return out
