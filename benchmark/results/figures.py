"""The figures pages, measured by one command and rendered from their data, never typed.

``trase-bench figures`` runs ``trase`` (or any ``--method``) on the five built-in formats with
reconstructed and with ground-truth geometry, for several run seeds, summarises the runs (mean
± std over seeds of test PSNR, geometry ceiling, oracle, mIoU, click-set median and worst,
clustering agreement) into a data file (``docs/figures.json``) with the commit and machine,
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
from benchmark.results.record import code_commit

FORMATS = ("nerfds", "hypernerf", "neu3d", "immersive", "technicolor")
GEOMETRIES = ("reconstruct", "ground-truth")
BEGIN = "<!-- FIGURES:BEGIN (trase-bench figures --write-page; do not edit by hand) -->"
END = "<!-- FIGURES:END -->"
METHODS_BEGIN = "<!-- METHODS:BEGIN (trase-bench figures --method ... --write-page; do not edit by hand) -->"
METHODS_END = "<!-- METHODS:END -->"
NAMES = {"nerfds": "NeRF-DS", "hypernerf": "HyperNeRF", "neu3d": "Neu3D", "immersive": "Immersive",
         "technicolor": "Technicolor"}
SCHEMA = "trase-bench/figures/1"


def run_all(out_dir: Path, seeds: list[int], formats=FORMATS, geometries=GEOMETRIES, progress: bool = True,
            methods=("trase",)) -> None:
    """Every (method, format, geometry) main-protocol run for every seed, into ``out_dir``
    (stages cached, so methods share a scene's masks and geometry; a run already there with
    this config is kept, so an interrupted measurement resumes where it stopped)."""
    from benchmark.runner import RunOptions, run

    for method in methods:
        for geo in geometries:
            for ds in formats:
                overrides = [] if geo == "reconstruct" else ["geometry.source=ground-truth"]
                run(RunOptions(method=method, dataset=ds, out_dir=Path(out_dir), overrides=overrides, seeds=seeds,
                               progress=progress, keep_existing=True))


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
    _check_schema(old)
    _check_schema(new)
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
    _check_schema(data)
    names, where = NAMES, _where(data)
    lines = [
        (f"Measured at commit `{data['commit']}` on {data['date']} ({where}), `trase-bench figures` (the "
         "main protocol of each format, official metric; mean ± standard deviation over the run seeds, "
         "seeds counted in the last column):"),
        "",
        ("| format | geometry | test PSNR (dB) | geometry ceiling | oracle | mIoU | click sets: median / worst "
         "| clusters agree (pixel ARI) | seeds |"),
        "|---|---|---|---|---|---|---|---|---|",
    ]
    mine = [r for r in data["rows"] if r.get("method", "trase") == "trase"]
    marks = _isa_marks(mine, data)
    for row in mine:
        s = row["summary"]
        geo = "reconstructed" if row["geometry"] == "reconstruct" else "ground truth"
        ag = (s.get("agreement") or {}).get("pixel_ari")
        psnr = _mean_std(row["test_psnr"]) if row["geometry"] == "reconstruct" else "—"
        lines.append(
            f"| {names.get(row['format'], row['format'])} | {geo} | {psnr} | {_ms(s['ceiling'])} | "
            f"{_ms(s['oracle'])} | **{_ms(s['miou'])}**{marks.get(_row_isa(row, data), '')} | {_ms(s['click_sets_median'])} / "
            f"{_ms(s['click_sets_worst'])} | {'—' if ag is None else f'{ag:.3f}'} | {len(s['seeds'])} |")
    note = _isa_note(mine, data, marks)
    return "\n".join(lines + ([""] + note if note else [])) + "\n"


def _check_schema(data: dict) -> None:
    if data.get("schema") != SCHEMA:
        raise UserError(f"figures data: schema {data.get('schema')!r}, expected {SCHEMA}")


def _where(data: dict) -> str:
    m = data["machine"]
    isa = m.get("instruction_sets") or []
    where = f"{m.get('cpus', '?')} CPU cores, {m.get('processor', '?')}"
    if len(isa) == 1:
        where += f"; {isa[0]}"
    elif isa:
        where += f"; runs from {len(isa)} instruction sets: " + " / ".join(isa)
    return where


def published_averages() -> dict[tuple[str, str], float]:
    """(method, format) -> the paper's average mIoU over that benchmark's sequences (its Table 1)."""
    from benchmark.results.leaderboard import published_frame

    df = published_frame()
    df = df[df["sequence"] == "_average"]
    return {(r.method, r.dataset): float(r.miou) for r in df.itertuples()}


def _order(scores: dict[str, float]) -> str:
    """Methods by decreasing score: "a > b > c"."""
    return " > ".join(m for m, _ in sorted(scores.items(), key=lambda kv: -kv[1]))


def render_methods_block(data: dict) -> str:
    """Every method's mIoU per format and geometry (mean ± std over seeds, oracle beside), the
    paper's published averages for the same methods, and the two orders per format. The
    measured rows are the built-in synthetic scenes, the published ones the real benchmarks:
    they sit side by side and are never mixed into one table."""
    _check_schema(data)
    rows = data["rows"]
    methods = list(dict.fromkeys(r.get("method", "trase") for r in rows))
    formats = [f for f in FORMATS if any(r["format"] == f for r in rows)]
    by = {(r.get("method", "trase"), r["format"], r["geometry"]): r for r in rows}
    code = data.get("run_commits")
    made = ""
    if code:
        made = (" from runs computed with the code of commit " + ", ".join(f"`{c}`" for c in code if c != "unrecorded")
                + (" and runs that do not record it (made before results recorded their commit)"
                   if "unrecorded" in code else "")) if any(c != "unrecorded" for c in code) else (
            " from runs that do not record their code's commit (made before results recorded it)")
    marks = _isa_marks(rows, data)
    lines = [(f"Summarised at commit `{data['commit']}` on {data['date']} ({_where(data)}){made}, `trase-bench figures "
             "--method ...` on the built-in synthetic scenes (each method's main protocol and defaults, "
             "official metric): mIoU, mean ± standard deviation over the run seeds; (n): the number of seeds "
             "where fewer than three."), ""]
    for geo in GEOMETRIES:
        if not any(r["geometry"] == geo for r in rows):
            continue
        lines += [f"**{'Reconstructed' if geo == 'reconstruct' else 'Ground-truth'} geometry**", "",
                  "| method | " + " | ".join(NAMES[f] for f in formats) + " |",
                  "|---|" + "---|" * len(formats)]
        for m in methods:
            cells = []
            for f in formats:
                r = by.get((m, f, geo))
                if r is None:
                    cells.append("—")
                    continue
                s, n = r["summary"], len(r["summary"]["seeds"])
                cells.append(_ms(s["miou"]) + (f" ({n})" if n < 3 else "") + marks.get(_row_isa(r, data), ""))
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
        lines.append("")
    note = _isa_note(rows, data, marks)
    lines += note + [""] if note else []
    pub = published_averages()
    pub_methods = list(dict.fromkeys([m for m in methods if any((m, f) in pub for f in formats)]
                                     + sorted({m for m, _ in pub})))  # measured ones first
    lines += ["**Published** (the paper's Table 1: real sequences, SAM masks, its own geometry per method)", "",
              "| method | " + " | ".join(NAMES[f] for f in formats) + " |", "|---|" + "---|" * len(formats)]
    for m in pub_methods:
        lines.append(f"| {m} | " + " | ".join(f"{pub[(m, f)]:.3f}" if (m, f) in pub else "—" for f in formats) + " |")
    lines += ["", "**Order** (methods measured here, by mIoU; the published order of the same methods)", "",
              "| format | measured, reconstructed | measured, ground truth | published |", "|---|---|---|---|"]
    for f in formats:
        orders = []
        for geo in GEOMETRIES:
            sc = {m: by[(m, f, geo)]["summary"]["miou"]["mean"] for m in methods if (m, f, geo) in by}
            orders.append(_order(sc) if len(sc) > 1 else "—")
        pb = {m: pub[(m, f)] for m in methods if (m, f) in pub}
        lines.append(f"| {NAMES[f]} | {orders[0]} | {orders[1]} | {_order(pb) if len(pb) > 1 else '—'} |")
    lines += _feature_time_lines(by, methods, lambda r: marks.get(_row_isa(r, data), ""))
    return "\n".join(lines) + "\n"


MARKS = ("†", "‡", "§", "¶")


def _row_isa(row: dict, data: dict) -> tuple[str, ...]:
    """The instruction sets of a row's runs (its file's for rows written before rows kept them)."""
    return tuple(row.get("instruction_sets") or data["machine"].get("instruction_sets") or ())


def _isas_by_share(rows: list[dict], data: dict) -> list[tuple[str, ...]]:
    """The rows' instruction sets, most cells first; on a tie the earlier measured first (rows
    without a date are the oldest), so a re-measurement never unmarks what it is merged into."""
    first = {}
    for r in rows:
        isa = _row_isa(r, data)
        first[isa] = min(first.get(isa, r.get("date") or ""), r.get("date") or "")
    count = lambda isa: sum(_row_isa(r, data) == isa for r in rows)
    return sorted(first, key=lambda isa: (-count(isa), first[isa]))


def _isa_marks(rows: list[dict], data: dict) -> dict[tuple[str, ...], str]:
    """A mark per instruction set other than the main one (``_isas_by_share``): cells of merged
    re-measurements (``figures --update``) say that their runs came from another machine."""
    others = _isas_by_share(rows, data)[1:]
    return {isa: MARKS[i % len(MARKS)] * (1 + i // len(MARKS)) for i, isa in enumerate(others)}


def _isa_note(rows: list[dict], data: dict, marks: dict) -> list[str]:
    """A line per mark: the instruction set, commits and dates of the marked cells' runs."""
    if not marks:
        return []
    name = lambda isa: " / ".join(isa) or "unrecorded"
    main = _isas_by_share(rows, data)[0]
    out = []
    for isa, mark in marks.items():
        mine = [r for r in rows if _row_isa(r, data) == isa]
        commits = sorted({c for r in mine for c in r.get("run_commits") or []} - {"unrecorded"})
        dates = sorted({r["date"] for r in mine if r.get("date")})
        out.append(f"{mark} runs computed with {name(isa)}"
                   + (f", the code of commit {', '.join(f'`{c}`' for c in commits)}" if commits else "")
                   + (f", on {', '.join(dates)}" if dates else "") + f"; the unmarked cells' with {name(main)}.")
    return out


DEFAULT_FORMAT = "hypernerf"  # the default scene (`make demo`)


def _feature_time_lines(by: dict, methods: list[str], mark=lambda row: "") -> list[str]:
    """Each method's feature stage on the default scene: median seconds and ms per step over
    its seeds, per geometry (measured inside the runs above: the machine's load at the time is
    in them; `trase-bench perf methods` measures them side by side)."""
    have = [m for m in methods if any(by.get((m, DEFAULT_FORMAT, g), {}).get("features_seconds") for g in GEOMETRIES)]
    if not have:
        return []
    import numpy as np

    title = (f"**Feature stage on the default scene** ({NAMES[DEFAULT_FORMAT]} format; median over the seeds "
             "of the runs above, each measured under the machine's load at its time)")
    lines = ["", title, "",
             "| method | reconstructed: s | ms per step | ground truth: s | ms per step |", "|---|---|---|---|---|"]
    for m in have:
        cells = []
        for geo in GEOMETRIES:
            r = by.get((m, DEFAULT_FORMAT, geo)) or {}
            sec, step = r.get("features_seconds") or [], r.get("features_per_step") or []
            cells += [f"{np.median(sec):.0f}{mark(r)}" if sec else "—", f"{np.median(step) * 1e3:.0f}" if step else "—"]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return lines


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


def page_block(text: str, where: str = PAGE, markers: tuple[str, str] = (BEGIN, END)) -> str:
    """The current block's content (between the markers)."""
    begin, end = markers
    if text.count(begin) != 1 or text.count(end) != 1:
        raise UserError(f"{where}: needs exactly one figures block ({begin} ... {end})")
    return text.split(begin, 1)[1].split(end, 1)[0].lstrip("\n")


def page_markers(text: str) -> tuple[tuple[str, str], object]:
    """Which block a page holds, and the function rendering it: the methods table's markers
    (several methods side by side) or trase's figures block."""
    if METHODS_BEGIN in text:
        return (METHODS_BEGIN, METHODS_END), render_methods_block
    return (BEGIN, END), render_block


def write_json(path: Path, data: dict) -> None:
    from benchmark.io import atomic_write_text

    atomic_write_text(path, json.dumps(data, indent=1) + "\n")
