"""The figures page (docs/figures.md), measured by one command and rendered from its data, never typed.

``trase-bench figures`` runs ``trase`` on the five built-in formats with reconstructed and
with ground-truth geometry, for several run seeds, summarises the runs (mean ± std over seeds
of test PSNR, geometry ceiling, oracle, mIoU, click-set median and worst, clustering
agreement) into ``docs/figures.json`` with the commit and machine they were measured on, and
rewrites the page's block between the FIGURES markers from that file. A test renders the
block from the file again and compares: the page's table cannot drift from its data.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
from pathlib import Path

from benchmark.errors import UserError

FORMATS = ("nerfds", "hypernerf", "neu3d", "immersive", "technicolor")
GEOMETRIES = ("reconstruct", "ground-truth")
BEGIN = "<!-- FIGURES:BEGIN (trase-bench figures --write-page; do not edit by hand) -->"
END = "<!-- FIGURES:END -->"
SCHEMA = "trase-bench/figures/1"


def _git_commit(root: Path) -> str:
    try:
        out = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, check=True, timeout=10)
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=False).stdout.strip()
        return out.stdout.strip() + ("+changes" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def run_all(out_dir: Path, seeds: list[int], formats=FORMATS, geometries=GEOMETRIES, progress: bool = True) -> None:
    """Every (format, geometry) main-protocol run for every seed, into ``out_dir`` (stages
    cached; a run already there with this config is kept, so an interrupted measurement
    resumes where it stopped)."""
    from benchmark.runner import RunOptions, run

    for geo in geometries:
        for ds in formats:
            overrides = [] if geo == "reconstruct" else ["geometry.source=ground-truth"]
            run(RunOptions(method="trase", dataset=ds, out_dir=Path(out_dir), overrides=overrides, seeds=seeds,
                           progress=progress, keep_existing=True))


def collect(out_dir: Path, formats=FORMATS, geometries=GEOMETRIES) -> dict:
    """Summaries of the runs under ``out_dir`` per (format, geometry), with provenance."""
    from benchmark.results.runs import find_runs, seed_siblings
    from benchmark.results.stability import seed_summary

    records = find_runs(Path(out_dir))
    rows, used = [], []
    for geo in geometries:
        for ds in formats:
            mine = [r for r in records if r["method"] == "trase" and r["dataset"] == ds
                    and r["config"]["geometry"]["source"] == geo and r["variant"] == "synthetic"]
            if not mine:
                continue
            groups = {r["run"]["group"] for r in mine}
            if len(groups) > 1:
                raise UserError(f"{out_dir}: {ds} with {geo} geometry has runs of {len(groups)} configs; "
                                "use a fresh --runs for the figures")
            sibs = seed_siblings(mine[0], mine)
            summary = seed_summary(sibs)
            used += sibs
            psnr = [(r["stages"]["geometry"].get("info") or {}).get("test_psnr") for r in sibs]
            seconds = [sum(s.get("seconds", 0.0) for k, s in r["stages"].items() if k in ("geometry", "features"))
                       for r in sibs]
            rows.append({"format": ds, "geometry": geo, "summary": summary,
                         "test_psnr": [p for p in psnr if p is not None], "seconds": seconds,
                         "scene": sibs[0].get("synthetic_scene"), "config_group": sibs[0]["run"]["group"],
                         "preset": sibs[0]["config"]["geometry"]["preset"]})
    if not rows:
        raise UserError(f"{out_dir}: no trase runs on the synthetic formats; run `trase-bench figures` first")
    machine = {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
               "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
               "instruction_sets": run_instruction_sets(used)}
    return {"schema": SCHEMA, "commit": _git_commit(Path(__file__).resolve().parent.parent),
            "date": datetime.date.today().isoformat(), "machine": machine, "rows": rows}


def run_instruction_sets(records: list[dict]) -> list[str]:
    """The distinct instruction sets the runs were computed with ("torch AVX512, numba znver5"),
    from each results file's ``machine``: they change a reconstruction's bits, and through it
    the figures (docs/determinism.md), so the page names them. Runs without the record count
    as "unrecorded"."""
    seen = []
    for r in records:
        m = r.get("machine") or {}
        cap, cpu = m.get("torch_cpu_capability"), m.get("numba_cpu")
        name = f"torch {cap}, numba {cpu}" if cap and cpu else "unrecorded"
        if name not in seen:
            seen.append(name)
    return sorted(seen)


def _ms(st: dict | None, digits: int = 3) -> str:
    if not st:
        return "—"
    s = f"{st['mean']:.{digits}f}"
    return s + (f" ± {st['std']:.{digits}f}" if st.get("std") is not None else "")


def _mean_std(values: list[float], digits: int = 2) -> str:
    import numpy as np

    if not values:
        return "—"
    v = np.asarray(values, float)
    return f"{v.mean():.{digits}f}" + (f" ± {v.std(ddof=1):.{digits}f}" if v.size > 1 else "")


def render_block(data: dict) -> str:
    """The figures block (markdown) from ``docs/figures.json``'s content. Stage seconds
    stay in the data file only: measured beside other work, they are not timings (see the perf
    suites for those)."""
    if data.get("schema") != SCHEMA:
        raise UserError(f"figures data: schema {data.get('schema')!r}, expected {SCHEMA}")
    names = {"nerfds": "NeRF-DS", "hypernerf": "HyperNeRF", "neu3d": "Neu3D", "immersive": "Immersive",
             "technicolor": "Technicolor"}
    m = data["machine"]
    isa = m.get("instruction_sets") or []
    where = f"{m.get('cpus', '?')} CPU cores, {m.get('processor', '?')}"
    if len(isa) == 1:
        where += f"; {isa[0]}"
    elif isa:
        where += f"; runs from {len(isa)} instruction sets: " + " / ".join(isa)
    lines = [
        (f"Measured at commit `{data['commit']}` on {data['date']} ({where}), `trase-bench figures` (the "
         "main protocol of each format, official metric; mean ± standard deviation over the run seeds, "
         "seeds counted in the last column):"),
        "",
        ("| format | geometry | test PSNR (dB) | geometry ceiling | oracle | mIoU | click sets: median / worst "
         "| clusters agree (pixel ARI) | seeds |"),
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in data["rows"]:
        s = row["summary"]
        geo = "reconstructed" if row["geometry"] == "reconstruct" else "ground truth"
        ag = (s.get("agreement") or {}).get("pixel_ari")
        psnr = _mean_std(row["test_psnr"]) if row["geometry"] == "reconstruct" else "—"
        lines.append(
            f"| {names.get(row['format'], row['format'])} | {geo} | {psnr} | {_ms(s['ceiling'])} | "
            f"{_ms(s['oracle'])} | **{_ms(s['miou'])}** | {_ms(s['click_sets_median'])} / "
            f"{_ms(s['click_sets_worst'])} | {'—' if ag is None else f'{ag:.3f}'} | {len(s['seeds'])} |")
    return "\n".join(lines) + "\n"


def read_figures(path: Path) -> dict:
    from benchmark.io import read_json

    return read_json(path, "figures file")


PAGE = "docs/figures.md"  # the page holding the block


def replace_block(text: str, block: str, where: str = PAGE) -> str:
    if text.count(BEGIN) != 1 or text.count(END) != 1 or text.index(BEGIN) > text.index(END):
        raise UserError(f"{where}: needs exactly one figures block ({BEGIN} ... {END})")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{block}{END}{tail}"


def page_block(text: str, where: str = PAGE) -> str:
    """The current block's content (between the markers)."""
    if text.count(BEGIN) != 1 or text.count(END) != 1:
        raise UserError(f"{where}: needs exactly one figures block ({BEGIN} ... {END})")
    return text.split(BEGIN, 1)[1].split(END, 1)[0].lstrip("\n")


def write_json(path: Path, data: dict) -> None:
    from benchmark.io import atomic_write_text

    atomic_write_text(path, json.dumps(data, indent=1) + "\n")
