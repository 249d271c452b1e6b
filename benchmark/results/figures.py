"""The figures pages, measured by one command and rendered from their data, never typed.

``trase-bench figures`` runs ``trase`` (or any ``--method``) on the five built-in formats with
reconstructed and with ground-truth geometry, for several run seeds (benchmark.commands.figures).
This module summarises the runs (mean ± std over seeds of test PSNR, geometry ceiling, oracle,
mIoU, click-set median and worst, clustering agreement) into a data file (``docs/figures.json``) with the commit and machine,
and rewrites a page's block from that file: between the FIGURES markers trase's table
(docs/figures.md), between the METHODS markers every method's mIoU side by side with the
paper's published averages and both orders (docs/competitors.md). A test renders each block
from its file again and compares: a page's table cannot drift from its data.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
from pathlib import Path

from benchmark.errors import UserError
from benchmark.numerics import pinning_name
from benchmark.results.figures_format import (
    FORMATS,
    GEOMETRIES,
    NAMES,
    SCHEMA,
    SINGLE_CLICK_NOTE,
    check_schema,
    isa_marks,
    isa_note,
    machine_line,
    mean_std,
    ms,
    row_isa,
)
from benchmark.results.figures_prompts import prompt_marks, prompt_note, row_prompts, run_prompt_settings
from benchmark.results.record import code_commit
from benchmark.results.runs import numerics_pinning

BEGIN = "<!-- FIGURES:BEGIN (trase-bench figures --write-page; do not edit by hand) -->"
END = "<!-- FIGURES:END -->"
METHODS_BEGIN = "<!-- METHODS:BEGIN (trase-bench figures --method ... --write-page; do not edit by hand) -->"
METHODS_END = "<!-- METHODS:END -->"


def collect(out_dir: Path, formats=FORMATS, geometries=GEOMETRIES, methods=("trase",)) -> dict:
    """Summaries of the runs under ``out_dir`` per (method, format, geometry), with provenance.
    A combination without runs is left out (a measurement still under way)."""
    from benchmark.results.runs import find_runs, seed_siblings
    from benchmark.results.stability import seed_summary

    records = find_runs(Path(out_dir))
    rows, used = [], []
    for method, geo, ds in ((m, g, d) for m in methods for g in geometries for d in formats):
        mine = [r for r in records if r["method"] == method and r["dataset"] == ds
                and r["config"]["geometry"]["source"] == geo and r["variant"] == "synthetic"
                and r["run"].get("kind", "main") != "ablation"]
        if not mine:
            continue
        groups = {r["run"]["group"] for r in mine}
        if len(groups) > 1:
            raise UserError(f"{out_dir}: {method} on {ds} with {geo} geometry has runs of {len(groups)} "
                            "configs; use a fresh --runs for the figures")
        sibs = seed_siblings(mine[0], mine)
        summary = seed_summary(sibs)
        used += sibs
        psnr = [(r["stages"]["geometry"].get("info") or {}).get("test_psnr") for r in sibs]
        seconds = [sum(s.get("seconds", 0.0) for k, s in r["stages"].items() if k in ("geometry", "features"))
                   for r in sibs]
        feats = [r["stages"].get("features") or {} for r in sibs]
        timings = [(f.get("info") or {}).get("timings") or {} for f in feats]
        rows.append({"method": method, "format": ds, "geometry": geo, "summary": summary,
                     "test_psnr": [p for p in psnr if p is not None], "seconds": seconds,
                     "features_seconds": [float(f["seconds"]) for f in feats if "seconds" in f],
                     "features_per_step": [float(t["features_per_step"]) for t in timings if "features_per_step" in t],
                     "scene": sibs[0].get("synthetic_scene"), "config_group": sibs[0]["run"]["group"],
                     "preset": sibs[0]["config"]["geometry"]["preset"],
                     "instruction_sets": run_instruction_sets(sibs), "run_commits": _run_commits(sibs),
                     "prompts": run_prompt_settings(sibs[0]),
                     "date": datetime.date.today().isoformat()})
    if not rows:
        raise UserError(f"{out_dir}: no runs of {', '.join(methods)} on the synthetic formats; "
                        "run `trase-bench figures` first")
    machine = {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
               "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
               "instruction_sets": run_instruction_sets(used)}
    return {"schema": SCHEMA, "commit": code_commit(),
            "date": datetime.date.today().isoformat(), "machine": machine, "rows": rows,
            "run_commits": _run_commits(used)}


def _run_commits(records: list[dict]) -> list[str]:
    return sorted({(r.get("versions") or {}).get("trase-bench commit", "unrecorded") for r in records})


def _row_key(row: dict) -> tuple[str, str, str]:
    return row.get("method", "trase"), row["format"], row["geometry"]


def merge(old: dict, new: dict) -> dict:
    """``old``'s data with ``new``'s rows in place of the same (method, format, geometry): a
    re-measurement of some cells (say one method's ground-truth row after a fix) keeps the rest.
    Each row keeps its own runs' instruction sets and commits (rows of files written before
    rows recorded them inherit their file's), so the page can say which cells came from where."""
    check_schema(old)
    check_schema(new)
    fresh = {_row_key(r): r for r in new["rows"]}
    old_isa = old.get("machine", {}).get("instruction_sets")
    rows = []
    for r in old["rows"]:
        if _row_key(r) in fresh:
            rows.append(fresh.pop(_row_key(r)))
            continue
        r = dict(r)
        if "instruction_sets" not in r and old_isa:
            r["instruction_sets"] = list(old_isa)
        if "run_commits" not in r:
            r["run_commits"] = list(old.get("run_commits") or ["unrecorded"])
        rows.append(r)
    rows += fresh.values()
    isa = sorted({i for r in rows for i in r.get("instruction_sets") or []})
    return dict(new, rows=rows, machine=dict(new["machine"], instruction_sets=isa),
                run_commits=sorted({c for r in rows for c in r.get("run_commits") or []}))


def run_instruction_sets(records: list[dict]) -> list[str]:
    """The distinct instruction sets the runs were computed with ("torch AVX512, numba znver5"),
    from each results file's ``machine``, with the portable pinning from the second on: they
    change a reconstruction's bits, and through it the figures (docs/determinism.md), so the
    page names them. Runs without the record count as "unrecorded"."""
    seen = []
    for r in records:
        m = r.get("machine") or {}
        cap, cpu = m.get("torch_cpu_capability"), m.get("numba_cpu")
        pinning = numerics_pinning(r.get("config") or {}, m)
        name = f"torch {cap}, numba {cpu}" if cap and cpu else "unrecorded"
        name = ", ".join(filter(None, (name, pinning_name(pinning) if cap and cpu else "")))
        if name not in seen:
            seen.append(name)
    return sorted(seen)


def render_block(data: dict) -> str:
    """The figures block (markdown) from ``docs/figures.json``'s content. Stage seconds
    stay in the data file only: measured beside other work, they are not timings (see the perf
    suites for those)."""
    check_schema(data)
    names, where = NAMES, machine_line(data)
    lines = [
        (f"Measured on {data['date']} ({where}), `trase-bench figures` (the "
         "main protocol of each format, official metric; mean ± standard deviation over the run seeds, "
         "seeds counted in the last column; mIoU after the robot user's corrections, mIoU@1 after the first "
         "clicks alone, NoC: clicks to reach mIoU 0.85 / 0.90, first clicks + budget + 1 where never):"),
        "",
        ("| format | geometry | test PSNR (dB) | geometry ceiling | oracle | mIoU | mIoU@1 | NoC@85 / NoC@90 "
         "| click sets: median / worst | clusters agree (pixel ARI) | seeds |"),
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    mine = [r for r in data["rows"] if r.get("method", "trase") == "trase"]
    marks, pmarks = isa_marks(mine, data), prompt_marks(mine)
    for row in mine:
        s = row["summary"]
        geo = "reconstructed" if row["geometry"] == "reconstruct" else "ground truth"
        ag = (s.get("agreement") or {}).get("pixel_ari")
        psnr = mean_std(row["test_psnr"]) if row["geometry"] == "reconstruct" else "—"
        single = "°" if not s.get("noc85") else ""  # runs of the first clicks alone
        lines.append(
            f"| {names.get(row['format'], row['format'])} | {geo} | {psnr} | {ms(s['ceiling'])} | "
            f"{ms(s['oracle'])} | **{ms(s['miou'])}**{single}{marks.get(row_isa(row, data), '')}"
            f"{pmarks.get(row_prompts(row), '')} | {ms(s.get('miou_at_1'))} | "
            f"{ms(s.get('noc85'), 1)} / {ms(s.get('noc90'), 1)} | {ms(s['click_sets_median'])} / "
            f"{ms(s['click_sets_worst'])} | {'—' if ag is None else f'{ag:.3f}'} | {len(s['seeds'])} |")
    note = isa_note(mine, data, marks) + prompt_note(mine, pmarks)
    if any(not r["summary"].get("noc85") for r in mine):
        note.append(SINGLE_CLICK_NOTE)
    return "\n".join(lines + ([""] + note if note else [])) + "\n"


def read_figures(path: Path) -> dict:
    from benchmark.io import read_json

    return read_json(path, "figures file")


PAGE = "docs/figures.md"  # the page holding the block


def replace_block(text: str, block: str, where: str = PAGE, markers: tuple[str, str] = (BEGIN, END)) -> str:
    begin, end = markers
    if text.count(begin) != 1 or text.count(end) != 1 or text.index(begin) > text.index(end):
        raise UserError(f"{where}: needs exactly one figures block ({begin} ... {end})")
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{begin}\n{block}{end}{tail}"


def write_blocks(path: Path, blocks: list[tuple[tuple[str, str], str]]) -> None:
    """Replace each (markers, block)'s text between its markers in the page at ``path``: one
    read, every block replaced in memory, one atomic write (a marker missing leaves the page as
    it was)."""
    from benchmark.io import atomic_write_text

    text = Path(path).read_text()
    for markers, block in blocks:
        text = replace_block(text, block, str(path), markers)
    atomic_write_text(Path(path), text)


def page_block(text: str, where: str = PAGE, markers: tuple[str, str] = (BEGIN, END)) -> str:
    """The current block's content (between the markers)."""
    begin, end = markers
    if text.count(begin) != 1 or text.count(end) != 1:
        raise UserError(f"{where}: needs exactly one figures block ({begin} ... {end})")
    return text.split(begin, 1)[1].split(end, 1)[0].lstrip("\n")


def page_markers(text: str) -> tuple[tuple[str, str], object]:
    """Which block a page holds, and the function rendering it: the README's results table,
    the methods table's markers (several methods side by side) or trase's figures block."""
    from benchmark.results.figures_summary import SUMMARY_BEGIN, SUMMARY_END, render_summary_block

    if SUMMARY_BEGIN in text:
        return (SUMMARY_BEGIN, SUMMARY_END), render_summary_block
    if METHODS_BEGIN in text:
        from benchmark.results.figures_methods import render_methods_block

        return (METHODS_BEGIN, METHODS_END), render_methods_block
    return (BEGIN, END), render_block


def write_json(path: Path, data: dict) -> None:
    from benchmark.io import atomic_write_text

    atomic_write_text(path, json.dumps(data, indent=1) + "\n")
