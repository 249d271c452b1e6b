"""Reconstruction quality against wall-clock time on the synthetic HyperNeRF-format scene.

Trains the runner's CPU geometry preset (the exact settings `trase-bench run` uses for this
scene) under a wall-clock budget (default 180 s), once per training resolution, saving a
checkpoint every few hundred iterations; then renders every checkpoint at the test views and
prints test PSNR against the time at which the checkpoint was written (setup and image loading
included), at full benchmark resolution and at the training resolution. Threads as in the
runner: torch on 1 thread (reconstruct's default), numba compositing on all cores (or
``trase-bench perf --threads N``).
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

BUDGET_S = 180.0
DOWNSCALES = (1.0, 2.0)  # the runner's CPU preset trains this scene at 1.0 (runner.cpu_train_downscale)
QUICK = {"size": "tiny", "budget_s": 10.0, "iterations": 60, "interval": 30}
FULL = {"size": "small", "budget_s": BUDGET_S, "iterations": None, "interval": 250}  # None: the runner's


def runner_train_config(dataset: str, image_size: tuple[int, int]) -> dict:
    """The geometry training settings `trase-bench run` picks for this scene on CPU."""
    from benchmark.datasets import get_dataset
    from benchmark.methods import get_method
    from benchmark.runner import default_config

    cfg = default_config(get_method("trase"), get_dataset(dataset), "synthetic", {"geometry": {"preset": "cpu"}},
                         image_size)
    return dict(cfg["geometry"]["train"])


def _train_and_score(scene, train: dict, downscale: float, budget_s: float, iterations: int | None,
                     interval: int, out_dir: Path, echo: Callable[[str], None]) -> dict:
    import numba

    from trase.checkpoint import available_iterations, load_model
    from trase.reconstruct import ReconstructionConfig, evaluate_psnr, reconstruct

    train = {**train, "image_downscale": downscale, "checkpoint_interval": interval}
    if iterations is not None:  # the quick smoke run: a few steps of the same schedule
        train["iterations"] = iterations
    cfg = ReconstructionConfig(**train)
    t0 = time.time()
    reconstruct(scene.train, scene.points, scene.point_colors, cfg, out_dir, resume=False, progress=False,
                max_seconds=budget_s)  # torch on 1 thread, as the runner (see reconstruct's docstring)
    wall = time.time() - t0
    curve = []
    for it in available_iterations(out_dir):
        ply = out_dir / "point_cloud" / f"iteration_{it}" / "point_cloud.ply"
        at = ply.stat().st_mtime - t0
        g, deform = load_model(out_dir, it)
        full = evaluate_psnr(g, deform, scene.test)
        train_res = full if downscale == 1 else evaluate_psnr(g, deform, scene.test, downscale=downscale)
        curve.append({"iteration": it, "seconds": at, "gaussians": g.num_gaussians,
                      "psnr_full": full, "psnr_train_res": train_res})
        echo(f"  train 1/{downscale:g} res: iteration {it:5d} at {at:6.1f}s  {g.num_gaussians:6d} gaussians  "
             f"test PSNR {full:5.2f} dB full res, {train_res:5.2f} dB at training res")
    last = curve[-1] if curve else None
    return {"downscale": downscale, "budget_s": budget_s, "wall_s": wall, "torch_threads": 1,
            "iterations_planned": cfg.iterations, "finished": bool(last and last["iteration"] == cfg.iterations),
            "numba_threads": numba.get_num_threads(),
            "curve": curve, "final": last}


def run(quick: bool = False, echo: Callable[[str], None] = print, dataset: str = "hypernerf") -> dict:
    from benchmark.datasets import load_scene
    from benchmark.datasets.synthetic.cache import ensure_synthetic

    st = QUICK if quick else FULL
    size, budget, iterations, interval = st["size"], st["budget_s"], st["iterations"], st["interval"]
    scene_dir = ensure_synthetic(dataset, size=size)
    scene = load_scene(dataset, scene_dir, gt_dir=scene_dir / "gt_masks")
    w, h = scene.test[0].camera.width, scene.test[0].camera.height
    train = runner_train_config(dataset, (w, h))
    echo(f"reconstruction: synthetic {dataset} ({size}, {w}x{h}, {len(scene.train)} train / {len(scene.test)} test "
         f"views), the runner's CPU preset ({iterations or train['iterations']} iterations), wall-clock budget "
         f"{budget:g}s per run")
    runs = []
    with tempfile.TemporaryDirectory(prefix="perf-recon-") as tmp:
        for ds in DOWNSCALES:
            runs.append(_train_and_score(scene, train, ds, budget, iterations, interval, Path(tmp) / f"ds{ds:g}",
                                         echo))
    for r in runs:
        f = r["final"]
        if f:
            done = "all" if r["finished"] else f"budget reached before {r['iterations_planned']}"
            echo(f"1/{r['downscale']:g} res training: {f['psnr_full']:.2f} dB full-res test PSNR after "
                 f"{f['seconds']:.0f}s ({f['iteration']} iterations, {done})")
    return {"description": __doc__.strip().splitlines()[0], "dataset": dataset, "size": size, "train_config": train,
            "image": f"{w}x{h}", "runs": runs,
            "load_average_end": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}
