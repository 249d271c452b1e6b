"""mIoU against run time for one scene over a grid of TRASE settings (feature iterations, Np,
clustering subsample fraction, feature dimension), plotted to PNG with the Pareto front marked.

The scene is the tiny synthetic NeRF-DS one (5.7k gaussians, 128x96): on 2 loaded CPU cores
one setting on the small scene takes minutes (pixel weights + evaluation alone ~90 s). The grid
is one-at-a-time around a base setting (a full factorial is 81 runs: hours on 2 CPU cores): the base, then each factor moved to its other values with the rest at base. Masks and
geometry (ground truth) are computed once and reused through the stage cache; each setting's
feature training, fit (clustering) and evaluation run fresh. Time = features + fit + evaluate
stage seconds (the stages the settings change; masks and geometry are shared). One run per setting: no spread.
An untimed warm-up run first (default settings) keeps imports and numba compilation out of
the first setting's time.
The Pareto front: settings no other setting beats on both time (lower) and mIoU (higher).
"""

from __future__ import annotations

import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from benchmark.perf.common import load_average, table, versions
from benchmark.perf.pipeline import run_pipeline

TIMED_STAGES = ("features", "fit", "evaluate")  # what the settings change (masks, geometry are shared)
FACTORS = {  # factor -> override key
    "iterations": "method.features.iterations",
    "n_pixels": "method.features.n_pixels",
    "fraction": "method.clustering.fraction",
    "dim": "method.features.dim",
}
DEFAULT = {"dataset": "nerfds", "sequence": "synthetic-tiny",
           "base": {"iterations": 20, "n_pixels": 1000, "fraction": 0.02, "dim": 32},
           "grid": {"iterations": [5, 60], "n_pixels": [300, 2000], "fraction": [0.10, 0.25], "dim": [8, 64]},
           "fixed": ["geometry.source=ground-truth"], "warmup": True}
QUICK = {"dataset": "nerfds", "sequence": "synthetic-tiny",
         "base": {"iterations": 2, "n_pixels": 200, "fraction": 0.02, "dim": 16},
         "grid": {"iterations": [4]},
         "fixed": ["geometry.source=ground-truth"], "warmup": False}


def settings_grid(base: dict, grid: dict) -> list[dict]:
    """One-at-a-time grid: [base] + base with one factor changed, for every listed value."""
    out = [dict(base)]
    for factor, values in grid.items():
        for v in values:
            if v != base[factor]:
                out.append({**base, factor: v})
    return out


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of (time, score) points not dominated (another point with time <= and score >=,
    one of them strictly), sorted by time."""
    front = []
    for i, (t, s) in enumerate(points):
        dominated = any((t2 <= t and s2 >= s) and (t2 < t or s2 > s) for j, (t2, s2) in enumerate(points) if j != i)
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: points[i][0])


def plot(runs: list[dict], front: list[int], path: Path, title: str,
         xlabel: str = "features + fit + evaluate time (s)", ylabel: str = "mIoU (official metric)") -> None:
    """Scatter of mIoU vs time (log x), each point labelled by what differs from the base;
    the Pareto front drawn as a line through its points."""
    import matplotlib.pyplot as plt

    fig = figure(runs, front, title, xlabel, ylabel)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


TITLE_CHARS = 90  # a title line at most this long fits the 7-inch figure at font size 9


def figure(runs: list[dict], front: list[int], title: str, xlabel: str, ylabel: str):
    """``plot``'s figure (matplotlib, Agg): the title wrapped to the figure's width, the time
    axis's ticks as plain seconds where the runs span less than a decade (log ticks would read
    2.8x10^2)."""
    import textwrap

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=120)
    xs = [r["seconds"] for r in runs]
    ys = [r["miou"] for r in runs]
    ax.scatter(xs, ys, c="tab:blue", label="setting")
    fx = [xs[i] for i in front]
    fy = [ys[i] for i in front]
    ax.plot(fx, fy, "-o", c="tab:red", label="Pareto front", zorder=3)
    for r in runs:
        ax.annotate(r["label"], (r["seconds"], r["miou"]), fontsize=7, xytext=(4, 3), textcoords="offset points")
    ax.set_xscale("log")
    positive = [x for x in xs if x > 0]
    if positive and max(positive) < 10 * min(positive):
        seconds = FuncFormatter(lambda v, _pos: f"{v:g}")
        ax.xaxis.set_major_formatter(seconds)
        ax.xaxis.set_minor_formatter(seconds)
        ax.tick_params(axis="x", which="minor", labelsize=7)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title("\n".join(textwrap.wrap(title, TITLE_CHARS)), fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def run(quick: bool = False, echo: Callable[[str], None] = print, out_dir: Path | None = None) -> dict:
    cfg = QUICK if quick else DEFAULT
    out_dir = Path(out_dir) if out_dir is not None else Path("perf-out")
    grid = settings_grid(cfg["base"], cfg["grid"])
    echo(f"Pareto: trase on {cfg['dataset']}/{cfg['sequence']}, {len(grid)} settings one-at-a-time around "
         f"{cfg['base']}; time = features + fit + evaluate; one run each (no spread)")
    runs, rows = [], []
    with tempfile.TemporaryDirectory(prefix="trase-perf-pareto-") as tmp:
        cache = Path(tmp) / "cache"  # shared: masks and geometry once, fit per setting (its key differs)
        if cfg["warmup"]:  # untimed: masks + geometry into the cache, imports, numba compilation
            run_pipeline(cfg["dataset"], cfg["sequence"], cfg["fixed"] + [f"{FACTORS['iterations']}=1"],
                         Path(tmp) / "out-warmup", cache)
        for k, s in enumerate(grid):
            changed = {f: v for f, v in s.items() if v != cfg["base"][f]}
            label = "base" if not changed else ", ".join(f"{f}={v}" for f, v in changed.items())
            overrides = cfg["fixed"] + [f"{FACTORS[f]}={v}" for f, v in s.items()]
            entry = {"settings": s, "label": label, "overrides": overrides}
            t0 = time.perf_counter()
            try:
                rec = run_pipeline(cfg["dataset"], cfg["sequence"], overrides, Path(tmp) / f"out-{k}", cache)
            except Exception as exc:  # noqa: BLE001 - reported per setting, not hidden
                entry["error"] = f"{type(exc).__name__}: {exc}"
                entry["traceback"] = traceback.format_exc(limit=3)
                rows.append([label, "FAILED", "", ""])
                echo(f"FAILED {label}: {entry['error']}")
                runs.append(entry)
                continue
            st = rec["stages"]
            timed = {k: float(v["seconds"]) for k, v in st.items() if k in TIMED_STAGES}
            entry.update(wall_seconds=time.perf_counter() - t0, miou=float(rec["metrics"]["official"]["miou"] or 0.0),
                         metric=rec["metrics"]["official"]["metric_version"],
                         stage_seconds=timed, seconds=sum(timed.values()),
                         cached=[k for k, v in st.items() if k in TIMED_STAGES and v.get("skipped")],
                         n_clusters=rec.get("n_clusters"), gaussians=rec.get("n_gaussians"))
            runs.append(entry)
    ok = [r for r in runs if "error" not in r]
    front = pareto_front([(r["seconds"], r["miou"]) for r in ok])
    for i, r in enumerate(ok):
        r["pareto"] = i in front
    for r in runs:
        if "error" not in r:
            rows.append([r["label"], f"{r['seconds']:.1f}", f"{r['miou']:.4f}", "*" if r["pareto"] else ""])
    echo(table(rows, ["setting", "time s", "mIoU (official)", "Pareto"]))
    png = None
    if ok:
        png = out_dir / "pareto.png"
        plot(ok, front, png, f"trase on {cfg['dataset']}/{cfg['sequence']} (synthetic), 2-core CPU")
        echo(f"wrote {png}")
    return {
        "description": __doc__.strip().splitlines()[0],
        "quick": quick,
        "settings": {**cfg, "method": "trase", "repeats": 1},
        "versions": versions("torch", "numba", "numpy", "sklearn", "matplotlib"),
        "runs": runs,
        "pareto_front": [ok[i]["label"] for i in front],
        "png": str(png) if png else None,
        "failed": [r["label"] for r in runs if "error" in r],
        "load_average_end": load_average(),
    }
