"""Rasterizer speed and agreement: the same random scene rendered by the numba backend and
the torch reference, forward and backward, side by side.

Each setting renders colour (3) + features (D) + depth + alpha and back-propagates a fixed
random linear functional of all outputs, so every gradient path runs. Times are wall-clock
medians over repeats (numba after one untimed warm-up that loads/compiles its kernels);
"spread" is max - min over the repeats. Process CPU time (all threads) is recorded beside the
wall time: on a shared, loaded machine it is the steadier of the two. Differences: max |output_numba - output_torch| over
colour, features, depth and alpha; gradient difference per input is
max |g_numba - g_torch| / max |g_torch|, the worst input reported. "state saved for the
backward" is what the numba forward keeps beyond its inputs and the tile binning (per-block
gaussian lists and lane masks, final transmittance; numba_backend.saved_state_bytes);
"backward scratch" is the per-entry gradient buffers the backend reuses across calls.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from collections.abc import Callable

import torch

from trase.camera import Camera, intrinsics, look_at
from trase.render import numba_backend, rasterize

# (gaussians, width, height, feature channels D (total channels = 3 + D), run torch?)
QUICK = [(5_000, 128, 96, 32, True)]
DEFAULT = [
    (5_000, 128, 96, 32, True),
    (20_000, 256, 192, 32, True),
    (100_000, 960, 536, 32, False),  # the torch reference would take minutes per pass here
]
INPUTS = ("means", "quats", "scales", "opacities", "colors", "features")


def make_scene(n: int, width: int, height: int, d: int, seed: int = 0) -> tuple[dict, Camera]:
    """Gaussians in a unit ball seen from distance 3 with a ~60 degree horizontal FOV; sizes
    shrink with n (as densified reconstructions do) so a few pixels of radius is typical."""
    g = torch.Generator().manual_seed(seed)
    f = 0.87 * width
    cam = Camera(K=intrinsics(f, f, width / 2, height / 2), w2c=look_at([0.0, -3.0, 0.4], [0.0, 0.0, 0.0]),
                 width=width, height=height)
    dirs = torch.randn(n, 3, generator=g)
    means = dirs / dirs.norm(dim=1, keepdim=True) * torch.rand(n, 1, generator=g) ** (1 / 3)
    log_s = -3.6 - math.log(n / 5_000) / 3
    scene = {
        "means": means,
        "quats": torch.randn(n, 4, generator=g),
        "scales": torch.exp(torch.randn(n, 3, generator=g) * 0.5 + log_s),
        "opacities": torch.sigmoid(torch.randn(n, generator=g)),
        "colors": torch.rand(n, 3, generator=g),
        "features": torch.randn(n, d, generator=g),
    }
    return scene, cam


def _once(backend: str, scene: dict, cam: Camera) -> tuple[float, float, float, float, dict, dict]:
    """-> (forward wall s, backward wall s, forward cpu s, backward cpu s, outputs, grads)."""
    leaves = {k: v.clone().requires_grad_(True) for k, v in scene.items()}
    g = torch.Generator().manual_seed(1)
    c0, t0 = time.process_time(), time.perf_counter()
    out = rasterize(camera=cam, backend=backend, **leaves)
    c1, t1 = time.process_time(), time.perf_counter()
    weights = [torch.rand(t.shape, generator=g) for t in (out.color, out.features, out.depth, out.alpha)]
    c1b, t1b = time.process_time(), time.perf_counter()
    loss = sum((t * w).sum() for t, w in zip((out.color, out.features, out.depth, out.alpha), weights))
    loss.backward()
    c2, t2 = time.process_time(), time.perf_counter()
    outs = {"color": out.color.detach(), "features": out.features.detach(),
            "depth": out.depth.detach(), "alpha": out.alpha.detach()}
    return t1 - t0, t2 - t1b, c1 - c0, c2 - c1b, outs, {k: leaves[k].grad for k in INPUTS}


def _stats(xs: list[float]) -> dict:
    return {"median": statistics.median(xs), "spread": max(xs) - min(xs), "all": xs}


def _time_backend(backend, scene, cam, repeats, warmup):
    if warmup:
        _once(backend, scene, cam)
    fw, bw, fc, bc = [], [], [], []
    for _ in range(repeats):
        f, b, cf, cb, outs, grads = _once(backend, scene, cam)
        fw.append(f)
        bw.append(b)
        fc.append(cf)
        bc.append(cb)
    return {
        "forward_s": _stats(fw),
        "backward_s": _stats(bw),
        "total_s": _stats([f + b for f, b in zip(fw, bw)]),
        "forward_cpu_s": _stats(fc),
        "backward_cpu_s": _stats(bc),
        "total_cpu_s": _stats([f + b for f, b in zip(fc, bc)]),
    }, outs, grads


def run(quick: bool = False, echo: Callable[[str], None] = print) -> dict:
    settings = QUICK if quick else DEFAULT
    reps_numba, reps_torch = (3, 2) if quick else (5, 3)
    rows = []
    echo(f"rasterizer: numba vs torch reference ({torch.get_num_threads()} torch threads, "
         f"{os.cpu_count()} cores); medians of {reps_numba} numba / {reps_torch} torch repeats, spread = max - min")
    for n, w, h, d, with_torch in settings:
        scene, cam = make_scene(n, w, h, d)
        label = f"{n // 1000}k gaussians {w}x{h} {3 + d}ch"
        row = {"gaussians": n, "width": w, "height": h, "channels": 3 + d, "feature_dim": d}
        num, out_n, g_n = _time_backend("numba", scene, cam, reps_numba, warmup=True)
        row["numba"] = num
        saved = dict(numba_backend.LAST_SAVED)  # what the latest numba forward kept for its backward
        row["numba_saved_bytes"] = {**saved, "total": sum(saved.values())}
        row["numba_scratch_bytes"] = numba_backend.scratch_bytes()  # backward buffers kept for reuse
        row["mean_alpha"] = float(out_n["alpha"].mean())
        echo(f"{label}: numba  forward {_fmt(num['forward_s'])}  backward {_fmt(num['backward_s'])}  "
             f"total {_fmt(num['total_s'])}  [cpu total {num['total_cpu_s']['median']:.3f}s]")
        echo(f"{label}: numba  state saved for the backward {_mib(row['numba_saved_bytes']['total'])} ("
             + ", ".join(f"{k} {_mib(v)}" for k, v in saved.items())
             + f"); backward scratch kept between calls {_mib(row['numba_scratch_bytes'])}")
        if with_torch:
            ref, out_t, g_t = _time_backend("torch", scene, cam, reps_torch, warmup=False)
            row["torch"] = ref
            row["speedup"] = {k: ref[k]["median"] / num[k]["median"] for k in num}
            row["max_abs_output_diff"] = max(float((out_n[k] - out_t[k]).abs().max()) for k in out_n)
            rel = {k: float((g_n[k] - g_t[k]).abs().max() / g_t[k].abs().max().clamp_min(1e-30)) for k in INPUTS}
            row["grad_rel_diff"] = rel
            row["max_grad_rel_diff"] = max(rel.values())
            s = row["speedup"]
            echo(f"{label}: torch  forward {_fmt(ref['forward_s'])}  backward {_fmt(ref['backward_s'])}  "
                 f"total {_fmt(ref['total_s'])}  [cpu total {ref['total_cpu_s']['median']:.3f}s]")
            echo(f"{label}: speed-up numba/torch forward {s['forward_s']:.1f}x  backward {s['backward_s']:.1f}x  "
                 f"forward+backward {s['total_s']:.1f}x (cpu time {s['total_cpu_s']:.1f}x);  max |output diff| {row['max_abs_output_diff']:.2e}  "
                 f"max gradient rel diff {row['max_grad_rel_diff']:.2e} ({max(rel, key=rel.get)})")
        else:
            echo(f"{label}: torch reference not run at this size (too slow: minutes per pass)")
        rows.append(row)
    return {
        "description": __doc__.strip().splitlines()[0],
        "quick": quick,
        "repeats": {"numba": reps_numba, "torch": reps_torch},
        "settings": rows,
        "load_average_end": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


def _mib(b: int) -> str:
    return f"{b / 2**20:.1f} MiB"


def _fmt(s: dict) -> str:
    return f"{s['median']:.3f}s (+-{s['spread'] / 2:.3f})"
