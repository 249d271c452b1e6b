"""The performance page's current figures, rendered from a ``trase-bench perf --json`` file
(docs/perf-runs/current.json): the rasterizer, the feature step, the objective, the smoothing
neighbours and the clustering, each row with its median and the machine that measured it."""

from __future__ import annotations

import json
from pathlib import Path

from benchmark.errors import UserError
from benchmark.numerics import pinning_name

PERF_BEGIN = ("<!-- PERF:BEGIN (trase-bench perf --json docs/perf-runs/current.json --from-json "
              "--write-page docs/performance.md; do not edit by hand) -->")
PERF_END = "<!-- PERF:END -->"
SUITES = ("raster", "features", "knn", "cluster")  # what the block reads


def _s(x: dict) -> str:
    """A median of seconds, in ms below one second."""
    v = float(x["median"])
    return f"{v * 1000:.1f} ms" if v < 1 else f"{v:.2f} s"


def raster_rows(suite: dict) -> list[tuple[str, str]]:
    out = []
    for s in suite["settings"]:
        what = (f"rasterizer, {s['gaussians']:,} gaussians, {s['width']}x{s['height']}, {s['channels']} channels, "
                "forward + backward")
        value = f"numba {_s(s['numba']['total_s'])}"
        if s.get("torch"):
            value += f", torch reference {_s(s['torch']['total_s'])} ({s['speedup']['total_s']:.1f}x)"
        out.append((what, value))
    return out


def feature_rows(suite: dict) -> list[tuple[str, str]]:
    out = []
    for key in ("whole_step", "whole_step_real_scale"):
        w = suite.get(key)
        if not w:
            continue
        t = w["threads"]["1"]
        what = f"feature step, {w['scene']} ({w['n_gaussians']:,} gaussians, {w['image']}, Np {w['n_pixels']}), one thread"
        ratio = t["step_raster"]["median"] / t["step_fast"]["median"]
        out.append((what, f"fast path {_s(t['step_fast'])}, rasterizer {_s(t['step_raster'])} ({ratio:.2f}x)"))
    for o in suite.get("objective_alone", []):
        out.append((f"objective, Np {o['n_pixels']}", f"fused {_s(o['fused_s'])}, dense {_s(o['reference_s'])}"))
    return out


def knn_rows(suite: dict) -> list[tuple[str, str]]:
    out = []
    for size in suite["sizes"]:
        methods = size["methods"]
        ours = next(v for k, v in methods.items() if k.startswith("trase.smoothing"))
        others = [f"{k} {_s(v['seconds'])}" for k, v in methods.items()
                  if not k.startswith("trase.smoothing") and "seconds" in v]
        out.append((f"K=16 neighbours, {size['n']:,} gaussians",
                    "; ".join([f"cKDTree, 1 thread (trase) {_s(ours['seconds'])}", *others])))
    return out


def cluster_rows(suite: dict) -> list[tuple[str, str]]:
    out = []
    for size in suite["sizes"]:
        configs = size["configs"]
        ref = configs.get(size["reference"], {})
        fixed = next(((k, v) for k, v in configs.items() if k.startswith("hdbscan fixed sample") and "PCA" not in k
                      and "seconds" in v), None)
        value = f"{size['reference']}: {_s(ref['seconds'])}" if "seconds" in ref else size["reference"]
        if fixed:
            value += f"; {fixed[0]}: {_s(fixed[1]['seconds'])}, ARI {fixed[1]['ari_vs_reference']:.4f} against it"
        out.append((f"HDBSCAN on 32-d features, {size['n']:,} gaussians", value))
    return out


ROWS = {"raster": raster_rows, "features": feature_rows, "knn": knn_rows, "cluster": cluster_rows}


def machine_line(data: dict) -> str:
    m = data["machine"]
    isa = "AVX-512" if (m.get("numerics") or {}).get("avx512") else "AVX2"
    numerics = m.get("numerics") or {}
    mode = numerics.get("mode", "native")
    label = f"{mode} numerics"
    if mode == "portable":  # its bits are its pinning's (benchmark.numerics.PINNING)
        label = " ".join(filter(None, (label, pinning_name(int(numerics.get("pinning", 1))))))
    return (f"{m.get('cpu_count', '?')} cores, {m.get('cpu', '?')} ({isa}), {label}, torch threads "
            f"{m.get('torch_threads', '?')}; measured {data.get('started', '?')[:10]}"
            f"{' (quick settings)' if any(s.get('quick') for s in data['suites'].values()) else ''}")


def render_perf_block(data: dict) -> str:
    """The figures table of a perf JSON file holding at least one of SUITES."""
    rows = [row for name in SUITES if isinstance(data["suites"].get(name), dict) and "skipped" not in data["suites"][name]
            for row in ROWS[name](data["suites"][name])]
    if not rows:
        raise UserError(f"the perf file holds none of the suites {', '.join(SUITES)}")
    lines = [f"Machine: {machine_line(data)}.", "", "| figure | median |", "|---|---|"]
    lines += [f"| {what} | {value} |" for what, value in rows]
    return "\n".join(lines) + "\n"


def write_perf_page(page: Path, data_path: Path, blocks: dict | None = None) -> None:
    """Put the block rendered from the perf JSON ``data_path`` between the page's markers.
    ``blocks``: {(begin, end) markers: render(data) -> text}, those the page may hold (default:
    the performance page's PERF block; the perf command adds the skip page's)."""
    from benchmark.results.figures import write_blocks

    blocks = blocks or {(PERF_BEGIN, PERF_END): render_perf_block}
    text = Path(page).read_text()
    found = [(markers, render) for markers, render in blocks.items() if markers[0] in text]
    if not found:
        names = " or ".join(begin.split(" ")[1] for begin, _ in blocks)
        raise UserError(f"{page}: no generated figures block (a {names} marker line)")
    try:
        data = json.loads(Path(data_path).read_text())
    except (OSError, ValueError) as exc:
        raise UserError(f"{data_path}: not a readable perf JSON file ({exc})") from None
    write_blocks(Path(page), [(markers, render(data)) for markers, render in found])


__all__ = ["PERF_BEGIN", "PERF_END", "SUITES", "render_perf_block", "write_perf_page"]
