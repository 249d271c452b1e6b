"""Per-stage wall time and peak memory of the whole pipeline (benchmark.runner) on each
synthetic dataset at two sizes, and how each stage's cost grows with image size and gaussian
count (exponents fitted by log-log least squares).

Every run uses a fresh stage cache (nothing is reused, every stage is measured) and the
settings in ``OVERRIDES``: ground-truth geometry (reconstruction on 2 CPU cores would take
tens of minutes per scene; its cost is not in these figures) and a short feature training,
so the fit stage's per-step time is what to extrapolate from (``fit.features_per_step``).
One run per setting: no spread; an untimed warm-up run first (default settings) keeps imports
and numba compilation out of the first run's stages. A dataset whose run fails is reported with its error (not
hidden) and left out of the fits.

Fits: for each stage, log(seconds) = a + b log(pixels per image) and, separately,
log(seconds) = a + c log(gaussians); and jointly log(s) = a + b log(px) + c log(g) when the
design is not degenerate. In the synthetic scenes the two drivers grow together between
sizes, so the one-driver exponents each carry the other's effect: read the joint fit (and
its condition number) for the split.
"""

from __future__ import annotations

import math
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmark.perf.common import load_average, table, versions

DATASETS = ["nerfds", "hypernerf", "neu3d", "immersive", "technicolor"]
OVERRIDES = ["geometry.source=ground-truth", "method.features.iterations=20", "method.features.n_pixels=1000"]
QUICK = {"datasets": ["nerfds"], "sizes": ["tiny"],
         "overrides": ["geometry.source=ground-truth", "method.features.iterations=2", "method.features.n_pixels=200"], "warmup": False}
DEFAULT = {"datasets": DATASETS, "sizes": ["tiny", "small"], "overrides": OVERRIDES, "warmup": True}
MAX_CORRELATION = 0.8  # joint fit only when pixels and gaussians vary independently enough
SEQUENCE = {"tiny": "synthetic-tiny", "small": "synthetic", "medium": "synthetic-medium"}


def run_pipeline(dataset: str, sequence: str, overrides: list[str], out_dir: Path, cache_dir: Path,
                 method: str = "trase") -> dict:
    """One benchmark.runner run -> its results.json record (stages, metrics, n_gaussians)."""
    from benchmark.results import load_results
    from benchmark.runner import RunOptions, run

    opts = RunOptions(method=method, dataset=dataset, sequences=[sequence], out_dir=Path(out_dir),
                      cache_dir=Path(cache_dir), overrides=list(overrides), progress=False)
    paths = run(opts)
    return load_results(paths[0])


def stage_table(record: dict) -> dict:
    """Record -> {stage: {seconds, peak_rss_mb, cached}} plus each stage's own ``info.timings``
    as ``<stage>.<part>`` (e.g. features_prepare, features_train, features_per_step, clustering)."""
    out = {}
    for name, s in record["stages"].items():
        out[name] = {"seconds": float(s["seconds"]), "peak_rss_mb": float(s["peak_rss_mb"]),
                     "cached": bool(s.get("skipped", False))}
    seen: dict[str, float] = {}  # a stage that passes on an earlier stage's timings: listed once
    for name, s in record["stages"].items():
        timings = (s.get("info") or {}).get("timings") or {}
        for k, v in timings.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool) and not k.startswith("n_"):
                if seen.get(k) == float(v):
                    continue
                seen[k] = float(v)
                out[f"{name}.{k}"] = {"seconds": float(v), "peak_rss_mb": None, "cached": False}
    return out


def fit_exponents(points: list[dict]) -> dict:
    """points: [{"pixels", "gaussians", "seconds"}] -> exponents of seconds in pixels and in
    gaussians: one-driver slopes, and the joint slopes with the design's condition number
    (None where the data cannot determine them: < 2 distinct values, < 3 points jointly, or a
    design too close to collinear for the split to mean anything: |corr| > MAX_CORRELATION)."""
    pts = [p for p in points if p["seconds"] > 0 and p["pixels"] > 0 and p["gaussians"] > 0]
    y = np.log([p["seconds"] for p in pts]) if pts else np.zeros(0)
    lp = np.log([p["pixels"] for p in pts]) if pts else np.zeros(0)
    lg = np.log([p["gaussians"] for p in pts]) if pts else np.zeros(0)

    def slope(x: np.ndarray) -> float | None:
        if len(x) < 2 or np.ptp(x) < 1e-9:
            return None
        A = np.stack([np.ones_like(x), x], 1)
        return float(np.linalg.lstsq(A, y, rcond=None)[0][1])

    out = {"n_points": len(pts), "pixels_exponent": slope(lp), "gaussians_exponent": slope(lg),
           "joint": None}
    if len(pts) >= 3:
        A = np.stack([np.ones_like(lp), lp - lp.mean(), lg - lg.mean()], 1)
        cond = float(np.linalg.cond(A))
        sp, sg = float(np.std(lp)), float(np.std(lg))
        corr = float(np.mean((lp - lp.mean()) * (lg - lg.mean())) / (sp * sg)) if sp > 1e-12 and sg > 1e-12 else 1.0
        if np.linalg.matrix_rank(A) == 3 and abs(corr) <= MAX_CORRELATION:
            coef, *_ = np.linalg.lstsq(A, y, rcond=None)
            out["joint"] = {"pixels_exponent": float(coef[1]), "gaussians_exponent": float(coef[2]),
                            "condition_number": cond, "driver_correlation": corr}
        else:
            out["joint_skipped"] = (f"drivers (nearly) collinear: correlation of log pixels and log gaussians "
                                    f"{corr:.2f} (|r| > {MAX_CORRELATION})")
    return out


def run(quick: bool = False, echo: Callable[[str], None] = print) -> dict:
    from benchmark.datasets.synthetic.rigs import SIZES

    cfg = QUICK if quick else DEFAULT
    echo(f"pipeline stages per synthetic dataset and size, fresh stage cache per run, settings: "
         f"{' '.join(cfg['overrides'])}; one run each (no spread)")
    runs, rows = [], []
    with tempfile.TemporaryDirectory(prefix="trase-perf-pipeline-") as tmp:
        if cfg["warmup"]:  # untimed: imports and numba compilation out of the first run's stages
            try:
                run_pipeline(cfg["datasets"][0], SEQUENCE[cfg["sizes"][0]], cfg["overrides"], Path(tmp) / "out-warmup",
                             Path(tmp) / "cache-warmup")
            except Exception:  # noqa: BLE001, S110 - the same run is repeated below and its error reported there
                pass
        for ds in cfg["datasets"]:
            for size in cfg["sizes"]:
                rig = SIZES[ds][size]
                entry = {"dataset": ds, "size": size, "sequence": SEQUENCE[size], "width": rig.width,
                         "height": rig.height, "pixels": rig.width * rig.height}
                t0 = time.perf_counter()
                try:
                    rec = run_pipeline(ds, SEQUENCE[size], cfg["overrides"], Path(tmp) / f"out-{ds}-{size}",
                                       Path(tmp) / f"cache-{ds}-{size}")
                except Exception as exc:  # noqa: BLE001 - reported per run (table + JSON), not hidden
                    entry["error"] = f"{type(exc).__name__}: {exc}"
                    entry["traceback"] = traceback.format_exc(limit=3)
                    rows.append([f"{ds} {size}", f"{rig.width}x{rig.height}", "", "FAILED (below)", "", ""])
                    runs.append(entry)
                    continue
                entry["wall_seconds"] = time.perf_counter() - t0
                entry["gaussians"] = int(rec["n_gaussians"])
                entry["miou"] = rec["metrics"]["official"]["miou"]  # the leaderboard's metric
                entry["metric"] = rec["metrics"]["official"]["metric_version"]
                entry["stages"] = stage_table(rec)
                runs.append(entry)
                for st, v in entry["stages"].items():
                    mem = "" if v["peak_rss_mb"] is None else f"{v['peak_rss_mb']:.0f}"
                    rows.append([f"{ds} {size}", f"{rig.width}x{rig.height}", str(entry["gaussians"]), st,
                                 f"{v['seconds']:.3f}", mem])
    echo(table(rows, ["run", "image", "gaussians", "stage", "seconds", "peak MiB"]))
    ok = [r for r in runs if "error" not in r]
    stages = sorted({s for r in ok for s in r["stages"]})
    fits = {}
    frows = []
    for st in stages:
        pts = [{"pixels": r["pixels"], "gaussians": r["gaussians"], "seconds": r["stages"][st]["seconds"]}
               for r in ok if st in r["stages"]]
        f = fits[st] = fit_exponents(pts)
        j = f["joint"] or {}
        frows.append([st, str(f["n_points"]), _e(f["pixels_exponent"]), _e(f["gaussians_exponent"]),
                      _e(j.get("pixels_exponent")), _e(j.get("gaussians_exponent")),
                      f"{j['condition_number']:.0f}" if j else ("collinear" if "joint_skipped" in f else "")])
    echo(table(frows, ["stage", "runs", "px exp (alone)", "gauss exp (alone)", "px exp (joint)",
                       "gauss exp (joint)", "cond"]))
    failed = [f"{r['dataset']} {r['size']}" for r in runs if "error" in r]
    for r in runs:
        if "error" in r:
            echo(f"FAILED {r['dataset']} {r['size']} (left out of the fits): {r['error']}")
    return {
        "description": __doc__.strip().splitlines()[0],
        "quick": quick,
        "settings": {**cfg, "method": "trase", "repeats": 1},
        "versions": versions("torch", "numba", "numpy", "sklearn"),
        "runs": runs,
        "exponents": fits,
        "failed": failed,
        "load_average_end": load_average(),
    }


def _e(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.2f}"
