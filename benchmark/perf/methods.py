"""Every method's feature stage on one built-in scene, side by side: seconds per step, the
stage's time, its peak memory (``trase-bench perf methods``).

Each method runs in a fresh process (its imports, numba compilation and memory are its own):
the benchmark's runner on the format's default synthetic scene with ground-truth geometry (no
reconstruction in the figures), the method's own preset for this machine, first an untimed
warm-up run of ``WARMUP_STEPS`` feature steps (compilation, masks, geometry), then the measured
run of ``steps`` steps with a fresh features stage. The per-step time is the method's own
(``features_per_step``: training time / steps); the stage's time at the preset's step count is
extrapolated from it (prepare + steps x per step) and labelled so. Memory: the process's
resident memory before the measured run and its peak during the features stage.
"""

from __future__ import annotations

import multiprocessing
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from benchmark.perf.common import load_average, table, versions

WARMUP_STEPS = 2
DEFAULT = {"sequence": "synthetic", "steps": 30, "methods": None}  # None: every registered method
QUICK = {"sequence": "synthetic-tiny", "steps": 3, "methods": ["trase"]}


def _overrides(steps: int, fastpath: bool | None = None) -> list[str]:
    out = ["geometry.source=ground-truth", f"method.features.iterations={steps}", "prompts.click_sets=1"]
    return out if fastpath is None else [*out, f"method.features.fastpath={str(fastpath).lower()}"]


def measure_method(method: str, dataset: str, sequence: str, steps: int, work: str) -> dict:
    """In a fresh process: warm-up run, then the measured run -> the features stage's figures.
    The measured run takes the render path (fast path or rasterizer) that the preset's own step
    count would take: "auto" decides by steps per view, and a few steps would rasterize."""
    from benchmark.cache import current_rss_mb
    from benchmark.datasets.loader import load_scene
    from benchmark.methods import get_method
    from benchmark.perf.pipeline import run_pipeline
    from lazyspecs.presets import Context
    from trase.features import use_fastpath

    work_dir = Path(work)
    cache = work_dir / "cache"  # masks and geometry shared by every method's process
    warm = run_pipeline(dataset, sequence, _overrides(WARMUP_STEPS), work_dir / f"warmup-{method}", cache,
                        method=method)
    preset = warm["config"]["method"].get("preset")
    settings = get_method(method).resolve_settings(preset, Context(dataset=dataset)).config
    feats = getattr(settings, "features", None)
    preset_steps = getattr(feats, "iterations", None)
    fast = None
    if preset_steps is not None and hasattr(feats, "fastpath"):
        n_views = len(load_scene(dataset, warm["scene_dir"]).train)
        fast = use_fastpath(feats.fastpath, int(preset_steps), n_views)
    baseline = current_rss_mb()
    rec = run_pipeline(dataset, sequence, _overrides(steps, fast), work_dir / f"out-{method}", cache, method=method)
    stage = rec["stages"]["features"]
    timings = (stage.get("info") or {}).get("timings") or {}
    per_step = timings.get("features_per_step")
    prepare = float(timings.get("features_prepare", 0.0)) + float(timings.get("features_scales", 0.0))
    return {
        "method": method, "preset": preset, "steps": steps, "gaussians": int(rec["n_gaussians"]),
        "path": {None: "-", True: "fast path", False: "rasterizer"}[fast],
        "stage_seconds": float(stage["seconds"]), "prepare_seconds": prepare,
        "per_step_seconds": None if per_step is None else float(per_step),
        "preset_steps": preset_steps,
        "stage_seconds_at_preset_steps": (None if per_step is None or preset_steps is None
                                          else prepare + float(per_step) * int(preset_steps)),
        "baseline_rss_mb": baseline, "peak_rss_mb": float(stage["peak_rss_mb"]),
    }


def _method_names(methods: list[str] | None) -> list[str]:
    from benchmark.methods import METHODS

    names = list(methods) if methods else METHODS.names()
    for n in names:
        METHODS.entry(n)  # an unknown name: one line naming it and the known ones, before any run
    return names


def run(quick: bool = False, echo: Callable[[str], None] = print, dataset: str = "hypernerf",
        methods: list[str] | None = None) -> dict:
    cfg = dict(QUICK if quick else DEFAULT)
    names = _method_names(methods or cfg["methods"])
    echo(f"feature stage per method on {dataset}/{cfg['sequence']}, ground-truth geometry, each method's preset "
         f"for this machine; {cfg['steps']} measured steps after a {WARMUP_STEPS}-step warm-up, one fresh process "
         "per method (no spread: one measured run each)")
    rows, out = [], []
    ctx = multiprocessing.get_context("spawn")  # a fresh interpreter: imports, compilation, memory its own
    with tempfile.TemporaryDirectory(prefix="trase-perf-methods-") as tmp:
        for name in names:
            t0 = time.perf_counter()
            try:
                with ctx.Pool(1) as pool:
                    r = pool.apply(measure_method, (name, dataset, cfg["sequence"], cfg["steps"], tmp))
            except Exception as exc:  # noqa: BLE001 - reported per method (table + JSON), not hidden
                out.append({"method": name, "error": f"{type(exc).__name__}: {exc}",
                            "traceback": traceback.format_exc(limit=3)})
                rows.append([name, "", "", "", "FAILED (below)", "", "", "", ""])
                continue
            r["wall_seconds"] = time.perf_counter() - t0
            out.append(r)
            ps = r["per_step_seconds"]
            at = r["stage_seconds_at_preset_steps"]
            rows.append([name, r["preset"], r["path"], str(r["gaussians"]),
                         "-" if ps is None else f"{ps * 1e3:.1f}", f"{r['prepare_seconds']:.1f}",
                         "-" if at is None else f"{at:.0f} ({r['preset_steps']})",
                         f"{r['baseline_rss_mb']:.0f}", f"{r['peak_rss_mb']:.0f}"])
    echo(table(rows, ["method", "preset", "path", "gaussians", "ms/step", "prepare s", "stage s at preset steps (extrap.)",
                      "MiB before", "peak MiB"]))
    for r in out:
        if "error" in r:
            echo(f"FAILED {r['method']}: {r['error']}")
    return {
        "description": __doc__.strip().splitlines()[0],
        "quick": quick,
        "settings": {**cfg, "dataset": dataset, "methods": names, "warmup_steps": WARMUP_STEPS,
                     "overrides": _overrides(cfg["steps"])},
        "versions": versions("torch", "numba", "numpy"),
        "methods": out,
        "failed": [r["method"] for r in out if "error" in r],
        "load_average_end": load_average(),
    }
