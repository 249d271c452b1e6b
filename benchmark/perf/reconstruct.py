"""Reconstruction quality against wall-clock time: the old and the new CPU presets side by side.

Trains the runner's geometry settings for the synthetic HyperNeRF-format scene (the `make
demo` scene) once per CPU preset (``cpu-v1``, the first one, ``cpu-v2``, the second,
``cpu-v3``, cpu-v2's schedule over twice the iterations, and ``cpu``, the current one: cpu-v3
with faint gaussians pruned; ``cpu-v4`` is the same there. With ``--dataset`` a multi-view
format: cpu-v2 and cpu-v3 are the same, and ``cpu`` trains the monocular schedule's 4000 iterations),
one after the other in this process (a preset whose settings equal an earlier one's on the scene
is reported as that one, not trained again), saving a checkpoint every few hundred iterations; then
renders every checkpoint at the test views and prints test PSNR against the time at which the
checkpoint was written (setup and image loading included), and the median seconds per
iteration before and after the deformation switches on. Threads as in the runner: torch as the
preset says (``torch_threads``), numba compositing on all cores (or ``trase-bench perf
--threads N``). Run it on a quiet machine: the presets are timed one after the other.
"""

from __future__ import annotations

import csv
import dataclasses
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

PRESETS = ("cpu-v1", "cpu-v2", "cpu-v3", "cpu")
QUICK = {"size": "tiny", "budget_s": 20.0, "iterations": 60, "interval": 30}
FULL = {"size": "small", "budget_s": 900.0, "iterations": None, "interval": 250}  # None: the preset's


def runner_train_config(dataset: str, image_size: tuple[int, int], preset: str = "cpu") -> dict:
    """The geometry training settings `trase-bench run` picks for this scene and preset, on the
    CPU (these suites measure the CPU reconstruction, also on a machine with a GPU)."""
    from benchmark.datasets import get_dataset
    from benchmark.methods import get_method
    from benchmark.pipeline.settings import run_settings

    settings = run_settings(get_method("trase"), get_dataset(dataset), "synthetic",
                            {"preset": preset, "geometry": {"train": {"device": "cpu"}}}, image_size)
    return dataclasses.asdict(settings.geometry.train)


def _seconds_per_iteration(log: Path, warm_up: int) -> dict:
    """Median seconds per logged iteration before and after the deformation switches on."""
    import numpy as np

    rows = list(csv.DictReader(log.open()))
    its = np.array([int(r["iteration"]) for r in rows], dtype=float)
    secs = np.array([float(r["seconds"]) for r in rows])
    if len(its) < 2:
        return {"static": None, "deforming": None}
    per = np.diff(secs) / np.diff(its)
    mid = its[1:]
    out = {}
    for name, sel in (("static", mid <= warm_up), ("deforming", mid > warm_up + 10)):
        out[name] = float(np.median(per[sel])) if sel.any() else None
    return out


def _train_and_score(scene, preset: str, train: dict, budget_s: float, iterations: int | None,
                     interval: int, out_dir: Path, echo: Callable[[str], None]) -> dict:
    import numba

    from trase.checkpoint import available_iterations, load_model
    from trase.reconstruct import ReconstructionConfig, reconstruct
    from trase.render_views import evaluate_psnr

    train = {**train, "checkpoint_interval": interval}
    if iterations is not None:  # the quick smoke run: a few steps of the same schedule
        train["iterations"] = iterations
    cfg = ReconstructionConfig(**train)
    t0 = time.time()
    reconstruct(scene.train, scene.points, scene.point_colors, cfg, out_dir, resume=False, progress=False,
                max_seconds=budget_s)  # torch threads: the preset's, as the runner
    wall = time.time() - t0
    curve = []
    for it in available_iterations(out_dir):
        ply = out_dir / "point_cloud" / f"iteration_{it}" / "point_cloud.ply"
        at = ply.stat().st_mtime - t0
        g, deform = load_model(out_dir, it)
        psnr = evaluate_psnr(g, deform, scene.test)
        curve.append({"iteration": it, "seconds": at, "gaussians": g.num_gaussians, "psnr": psnr})
        echo(f"  {preset:<7} iteration {it:5d} at {at:6.1f}s  {g.num_gaussians:6d} gaussians  test PSNR {psnr:5.2f} dB")
    last = curve[-1] if curve else None
    return {"preset": preset, "train_config": train, "budget_s": budget_s, "wall_s": wall, "torch_threads": cfg.torch_threads,
            "numba_threads": numba.get_num_threads(), "iterations_planned": cfg.iterations,
            "finished": bool(last and last["iteration"] == cfg.iterations),
            "seconds_per_iteration": _seconds_per_iteration(out_dir / "train_log.csv", cfg.warm_up),
            "curve": curve, "final": last}


def run(quick: bool = False, echo: Callable[[str], None] = print, dataset: str = "hypernerf") -> dict:
    from benchmark.datasets import load_scene
    from benchmark.datasets.synthetic.cache import ensure_synthetic

    st = QUICK if quick else FULL
    size, budget, iterations, interval = st["size"], st["budget_s"], st["iterations"], st["interval"]
    scene_dir = ensure_synthetic(dataset, size=size)
    scene = load_scene(dataset, scene_dir, gt_dir=scene_dir / "gt_masks")
    w, h = scene.test[0].camera.width, scene.test[0].camera.height
    echo(f"reconstruction: synthetic {dataset} ({size}, {w}x{h}, {len(scene.train)} train / {len(scene.test)} test "
         f"views), the runner's geometry settings per CPU preset, wall-clock budget {budget:g}s per run")
    runs = []
    with tempfile.TemporaryDirectory(prefix="perf-recon-") as tmp:
        for preset in PRESETS:
            train = runner_train_config(dataset, (w, h), preset)
            twin = next((r["preset"] for r in runs if r["runner_config"] == train), None)
            if twin is not None:  # e.g. cpu-v3 on a multi-view rig: cpu-v2's settings, trained once
                echo(f"  {preset:<7} the same settings as {twin} on this scene: not trained again")
                runs.append({"preset": preset, "same_as": twin, "runner_config": train})
                continue
            run_ = _train_and_score(scene, preset, train, budget, iterations, interval, Path(tmp) / preset, echo)
            runs.append({**run_, "runner_config": train})
    echo(f"{'preset':<8} {'iterations':>10} {'seconds':>8} {'test PSNR':>10} {'s/it static':>12} {'s/it deforming':>15}")
    for r in runs:
        if "same_as" in r:
            echo(f"{r['preset']:<8} = {r['same_as']}")
            continue
        f, spi = r["final"], r["seconds_per_iteration"]
        if f:
            def fmt(x):
                return f"{x:.3f}" if x is not None else "-"
            done = "" if r["finished"] else f" (budget reached before {r['iterations_planned']})"
            echo(f"{r['preset']:<8} {f['iteration']:>10} {f['seconds']:>8.0f} {f['psnr']:>7.2f} dB "
                 f"{fmt(spi['static']):>12} {fmt(spi['deforming']):>15}{done}")
    return {"description": __doc__.strip().splitlines()[0], "dataset": dataset, "size": size,
            "image": f"{w}x{h}", "runs": runs,
            "load_average_end": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}
