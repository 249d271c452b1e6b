"""The methods table of docs/competitors.md, rendered from its data file
(``trase-bench figures --method ...``): every method's mIoU per format and geometry beside the
paper's published averages, both orders, the corrective protocol's figures, and the feature
stage's time on the default scene."""

from __future__ import annotations

from benchmark.results.figures_format import (
    FORMATS,
    GEOMETRIES,
    NAMES,
    SINGLE_CLICK_NOTE,
    check_schema,
    isa_marks,
    isa_note,
    machine_line,
    ms,
    row_isa,
)
from benchmark.results.figures_prompts import prompt_marks, prompt_note, row_prompts


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
    check_schema(data)
    rows = data["rows"]
    methods = list(dict.fromkeys(r.get("method", "trase") for r in rows))
    formats = [f for f in FORMATS if any(r["format"] == f for r in rows)]
    by = {(r.get("method", "trase"), r["format"], r["geometry"]): r for r in rows}
    marks, pmarks = isa_marks(rows, data), prompt_marks(rows)
    lines = [(f"Summarised on {data['date']} ({machine_line(data)}; each run's code commit is in the data file), `trase-bench figures "
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
                single = "°" if not s.get("noc85") else ""  # runs of the first clicks alone
                cells.append(ms(s["miou"]) + single + (f" ({n})" if n < 3 else "") + marks.get(row_isa(r, data), "")
                             + pmarks.get(row_prompts(r), ""))
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
        lines.append("")
    note = isa_note(rows, data, marks) + prompt_note(rows, pmarks)
    if any(not r["summary"].get("noc85") for r in rows):
        note = [*note, SINGLE_CLICK_NOTE]
    lines += note + [""] if note else []
    pub = published_averages()
    pub_methods = list(dict.fromkeys([m for m in methods if any((m, f) in pub for f in formats)]
                                     + sorted({m for m, _ in pub})))  # measured ones first
    lines += ["**Published** (the paper's Table 1: real sequences, SAM masks, its own geometry per method, a person's clicks)", "",
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
    lines += _clicks_lines(by, methods, formats, lambda r: pmarks.get(row_prompts(r), ""))
    lines += _feature_time_lines(by, methods, lambda r: marks.get(row_isa(r, data), ""))
    return "\n".join(lines) + "\n"


DEFAULT_FORMAT = "hypernerf"  # the default scene (`make demo`)


def _clicks_lines(by: dict, methods: list[str], formats: list[str], mark=lambda row: "") -> list[str]:
    """Per geometry, each method's first clicks' mIoU (mIoU@1) and the clicks the robot user
    needed to reach mIoU 0.85 / 0.90 (benchmark.pipeline.corrective), means over the seeds;
    ``mark``: a row's mark of other prompt settings."""
    lines = []
    for geo in GEOMETRIES:
        rows = [m for m in methods if any((by.get((m, f, geo)) or {}).get("summary", {}).get("noc85") for f in formats)]
        if not rows:
            continue
        title = (f"**Clicks, {'reconstructed' if geo == 'reconstruct' else 'ground-truth'} geometry** "
                 "(mIoU@1: the first clicks alone; NoC@85 / NoC@90: clicks to reach that mIoU, the first "
                 "clicks + budget + 1 where never; means over the seeds)")
        lines += ["", title, "",
                  "| method | " + " | ".join(NAMES[f] for f in formats) + " |", "|---|" + "---|" * len(formats)]
        for m in rows:
            cells = []
            for f in formats:
                r = by.get((m, f, geo)) or {}
                s = r.get("summary") or {}
                cells.append("—" if not s.get("noc85") else
                             f"{ms(s.get('miou_at_1'))}; {ms(s['noc85'], 1)} / {ms(s.get('noc90'), 1)}{mark(r)}")
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return lines


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
