"""Helpers shared by the perf suites: repeated timing, median + spread, formatting, library
versions, peak memory. A suite measures alternatives side by side in one process, so the
load on the machine (shared cores) hits every alternative alike; spread = max - min over the
repeats says how noisy that was.
"""

from __future__ import annotations

import gc
import importlib
import os
import statistics
import time
from collections.abc import Callable


def stats(xs: list[float]) -> dict:
    """Repeated measurements -> {"median", "spread" (max - min), "all"}."""
    xs = [float(x) for x in xs]
    if not xs:
        return {"median": float("nan"), "spread": 0.0, "all": []}
    return {"median": statistics.median(xs), "spread": max(xs) - min(xs), "all": xs}


def fmt(s: dict, unit: str = "s") -> str:
    """``1.234s (+-0.050)``: median and half the spread."""
    return f"{s['median']:.3f}{unit} (+-{s['spread'] / 2:.3f})"


def time_repeats(fn: Callable[[], object], repeats: int, warmup: int = 0,
                 budget_s: float | None = None) -> tuple[dict, object]:
    """Call ``fn`` ``warmup`` times untimed, then ``repeats`` times timed (wall clock).

    ``budget_s``: stop repeating once the timed calls took this long in total (at least one
    call always runs), so a slow alternative does not take minutes; the stats say how many ran.
    Returns (stats of the seconds, the last return value). A garbage collection before each
    call keeps one alternative's garbage from being billed to the next."""
    out = None
    for _ in range(warmup):
        out = fn()
    times: list[float] = []
    for _ in range(max(int(repeats), 1)):
        gc.collect()
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
        if budget_s is not None and sum(times) >= budget_s:
            break
    return stats(times), out


def ratio(a: dict, b: dict) -> float:
    """Median of a / median of b (how many times slower a is than b)."""
    return float(a["median"]) / max(float(b["median"]), 1e-12)


def versions(*modules: str) -> dict:
    """{module: __version__} for the libraries a suite measures (missing ones say so)."""
    out = {}
    for m in modules:
        try:
            out[m] = getattr(importlib.import_module(m), "__version__", "unknown")
        except ImportError:
            out[m] = "not installed"
    return out


def load_average() -> list[float] | None:
    return list(os.getloadavg()) if hasattr(os, "getloadavg") else None


def table(rows: list[list[str]], header: list[str]) -> str:
    """Plain fixed-width text table (first column left-aligned, others right-aligned)."""
    cols = [header] + rows
    widths = [max(len(str(r[i])) for r in cols) for i in range(len(header))]

    def line(r):
        return "  ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(r, widths)))

    return "\n".join([line(header), line(["-" * w for w in widths])] + [line(r) for r in rows])
