"""Leaderboard tables (benchmark.results.leaderboard) rendered as markdown, LaTeX, CSV or HTML:
the best value of each column in bold, ± the spread over seeds, ≈ within the spread of the best,
the v1 metric where it differs."""

from __future__ import annotations

import html
import io
import math

import pandas as pd

from benchmark.results.leaderboard import Table, build_tables

FORMATS = ("markdown", "latex", "csv", "html")


def _fmt(x: float | None, digits: int = 4) -> str:
    return "—" if x is None else f"{x:.{digits}f}"


def _digits(table: Table, i: int) -> int:
    """Scores to 4 decimals, click counts (means over sequences and seeds) to 2."""
    return 2 if table.column(i) in table.lower_is_better else 4


def _fmt_time(x: float | None) -> str:
    return "—" if x is None or math.isnan(x) else f"{x:.1f}"


def render(table: Table, fmt: str) -> str:
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    return {"markdown": _markdown, "latex": _latex, "csv": _csv, "html": _html}[fmt](table)


def _tail_head(t: Table) -> list[str]:
    """The columns after the cells: seconds per sequence (a timed table) and seeds."""
    return (["s/seq"] if t.timed else []) + (["seeds"] if t.has_seeds() else [])


def _cells(table: Table, bold: callable, pm: str = "±", approx: str = "≈") -> list[tuple[str, list[str], list[str]]]:
    """(label, cell texts, [time text,] [seeds text]) per row: the mean (bold if best), ± its
    spread, ≈ when within the spread of the best, the v1 metric where it differs."""
    best = table.best()
    seeds_col = table.has_seeds()
    out = []
    for row in table.rows:
        v1 = row.v1 or [None] * len(row.cells)
        txt = []
        for i, v in enumerate(row.cells):
            d = _digits(table, i)
            t = bold(_fmt(v, d)) if v is not None and v == best[i] else _fmt(v, d)
            sd = row.spread[i] if row.spread else None
            if v is not None and sd is not None:
                t += f" {pm} {_fmt(sd, d)}"
            if table.within_spread(row, i, best[i]):
                t = f"{approx}{t}"
            if v is not None and v1[i] is not None and _fmt(v1[i]) != _fmt(v):
                t += f" (v1 {_fmt(v1[i])})"
            txt.append(t)
        tail = [_fmt_time(row.seconds)] if table.timed else []
        if seeds_col:
            tail.append("—" if row.seeds is None else str(row.seeds))
        out.append((row.label, txt, tail))
    return out


def _markdown(t: Table) -> str:
    head = ["method"] + [f"{g} {c}" for g in t.groups for c in t.columns] + _tail_head(t)
    lines = [f"### {t.title}", "", "| " + " | ".join(head) + " |",
             "|" + "|".join(["---"] + ["---:"] * (len(head) - 1)) + "|"]
    for label, cells, tail in _cells(t, lambda s: f"**{s}**"):
        lines.append("| " + " | ".join([label] + cells + tail) + " |")
    lines += [""] + [f"- {n}" for n in t.notes]
    return "\n".join(lines).rstrip() + "\n"


def _latex(t: Table) -> str:
    esc = lambda s: s.replace("_", r"\_").replace("%", r"\%")
    tail = _tail_head(t)
    top = {"s/seq": "Time", "seeds": "Seeds"}
    lines = [r"\begin{table}[t]", r"\centering", r"\caption{" + esc(t.title) + "}",
             r"\begin{tabular}{l" + "c" * len(t.columns) * len(t.groups) + "r" * len(tail) + "}",
             r"\toprule",
             "Method & " + " & ".join([rf"\multicolumn{{{len(t.columns)}}}{{c}}{{" + esc(g) + "}" for g in t.groups]
                                      + [top[c] for c in tail]) + r" \\",
             " & " + " & ".join([" & ".join(t.columns)] * len(t.groups) + [c if c == "s/seq" else "" for c in tail])
             + r" \\", r"\midrule"]
    for label, cells, row_tail in _cells(t, lambda s: r"\textbf{" + s + "}", pm=r"$\pm$", approx=r"$\approx$"):
        lines.append(" & ".join([esc(label)] + cells + row_tail) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    if t.notes:  # protocol footnotes and the metric note
        lines += [r"\par\footnotesize"] + [esc(n) + r"\\" for n in t.notes]
    lines += [r"\end{table}"]
    return "\n".join(lines) + "\n"


def _csv(t: Table) -> str:
    rows = []
    for r in t.rows:
        row = {"table": t.title, "method": r.label}
        v1 = r.v1 or [None] * len(r.cells)
        spread = r.spread or [None] * len(r.cells)
        k = len(t.columns)
        for i, g in enumerate(t.groups):
            for j, c in enumerate(t.columns):
                name = f"{g}_{c.lower().replace('@', '')}"
                row[name], row[f"{name}_std"] = r.cells[k * i + j], spread[k * i + j]
                if v1[k * i + j] is not None or c in ("mIoU", "mAcc"):
                    row[f"{name}_v1"] = v1[k * i + j]
        if t.timed:
            row["seconds_per_sequence"] = r.seconds
        row["seeds"] = r.seeds
        row["protocol"] = r.protocol
        rows.append(row)
    buf = io.StringIO()
    pd.DataFrame(rows).to_csv(buf, index=False)
    return buf.getvalue()


def _html(t: Table) -> str:
    e = html.escape
    head = "".join(f'<th colspan="{len(t.columns)}">{e(g)}</th>' for g in t.groups)
    sub = "".join("".join(f"<th>{e(c)}</th>" for c in t.columns) for _ in t.groups)
    body = "".join(
        "<tr><td>" + e(label) + "</td>" + "".join(f"<td>{c}</td>" for c in cells + tail) + "</tr>"
        for label, cells, tail in _cells(t, lambda s: f"<b>{s}</b>")
    )
    notes = "".join(f"<li>{e(n)}</li>" for n in t.notes)
    tail_head = "".join(f"<th rowspan=2>{e(c)}</th>" for c in _tail_head(t))
    return (f"<h3>{e(t.title)}</h3><table><thead><tr><th rowspan=2>method</th>{head}"
            f"{tail_head}</tr><tr>{sub}</tr></thead><tbody>{body}</tbody></table>"
            + (f"<ul>{notes}</ul>" if notes else "") + "\n")


def render_all(records: list[dict], fmt: str = "markdown", variants=("synthetic", "real"),
               published: bool = True) -> str:
    parts = []
    for v in variants:
        for t in build_tables(records, v, published=published):
            parts.append(render(t, fmt))
    if fmt == "html":
        style = ("<style>body{font-family:sans-serif}table{border-collapse:collapse;margin:1em 0}"
                 "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
                 "td:first-child{text-align:left}</style>")
        return f"<!doctype html><html><head><meta charset='utf-8'>{style}</head><body>" + \
            "".join(parts) + "</body></html>\n"
    return "\n".join(parts)
