"""Leaderboards rendered from runs (and the paper's published numbers), never typed.

Layout follows the paper's Table 1: one row per method, a (mIoU, mAcc) column pair per
benchmark, the best value of each column in bold, and a time column. Per-sequence tables
follow the supplementary. Rules:

* the caller chooses the runs (``benchmark.runs``: by default each method's main run), and a
  cell is one run: two configs for one (method, dataset, sequence) are refused before this;
* every measured row carries its protocol (geometry, features preset, masks, prompts, render
  rule, metric) as a footnote marker;
* cells use the official metric, the one the published rows were made with; the project's
  ``v1`` is shown beside a cell where it differs;
* real and synthetic results never share a table (``variant``);
* published numbers appear only beside real results, as separate rows labelled
  ``(published)``, with the supplementary's own average;
* a dataset average is shown only when the method ran every sequence of that dataset
  (real: the paper's list; synthetic: every synthetic sequence any method ran).
"""

from __future__ import annotations

import dataclasses
import html
import io
import math
from importlib import resources
from typing import NamedTuple

import pandas as pd

from benchmark.datasets import DATASETS
from benchmark.results import total_seconds
from benchmark.runs import ProtocolLegend, protocol, protocol_label

FORMATS = ("markdown", "latex", "csv", "html")
PUBLISHED_NOTE = (
    "Published rows: the TRASE paper's supplementary per-sequence tables and their Average "
    "column (OpenGaussian on HyperNeRF-Mask: Table 1 says 0.6311/0.9411, the supplementary "
    "0.6531/0.9480; SA4D on Neu3D-Mask mAcc: Table 1 0.9391, supplementary 0.9931)."
)
METRIC_NOTE = ("Measured cells: the official metric (the public evaluation script's rules, which the "
               "paper's numbers were made with); the project's v1 metric in brackets where it differs.")


class Row(NamedTuple):
    label: str  # method, its protocol marks, or "(published)"
    cells: list[float | None]  # [miou, macc] * groups, official metric
    seconds: float | None  # per sequence
    v1: list[float | None] | None = None  # the v1 metric's cells (None: published row)
    protocol: str = ""  # the protocol label(s) behind the marks


@dataclasses.dataclass
class Table:
    title: str
    groups: list[str]  # one per column pair (dataset or sequence)
    rows: list[Row]
    notes: list[str] = dataclasses.field(default_factory=list)

    def best(self) -> list[float | None]:
        n = 2 * len(self.groups)
        cols = [[r[1][i] for r in self.rows if r[1][i] is not None] for i in range(n)]
        return [max(c) if c else None for c in cols]


# -- data ------------------------------------------------------------------------------------
def measured_frame(records: list[dict]) -> pd.DataFrame:
    """One row per run: official metric (``miou``, ``macc``), v1 beside, protocol label."""
    rows = [
        {
            "variant": r["variant"],
            "dataset": r["dataset"],
            "sequence": r["sequence"],
            "method": r["method"],
            "miou": r["metrics"]["official"]["miou"],
            "macc": r["metrics"]["official"]["macc"],
            "miou_v1": r["metrics"]["miou"],
            "macc_v1": r["metrics"]["macc"],
            "seconds": total_seconds(r),
            "source": "measured",
            "protocol": protocol_label(protocol(r)),
        }
        for r in records
    ]
    return pd.DataFrame(rows, columns=COLUMNS)


COLUMNS = ["variant", "dataset", "sequence", "method", "miou", "macc", "miou_v1", "macc_v1", "seconds",
           "source", "protocol"]


def published_frame() -> pd.DataFrame:
    """The paper's per-sequence numbers (package data); ``_average`` rows are its averages."""
    path = resources.files("benchmark") / "data" / "published" / "trase_paper_per_sequence.csv"
    with path.open() as f:
        df = pd.read_csv(f)
    df["variant"] = "real"
    df["source"] = "published"
    df["seconds"] = math.nan
    df["miou_v1"] = df["macc_v1"] = math.nan
    df["protocol"] = ""
    return df


# -- tables ----------------------------------------------------------------------------------
def _expected_sequences(df: pd.DataFrame, variant: str, dataset: str) -> list[str]:
    if variant == "real" and dataset in DATASETS:
        return list(DATASETS[dataset].sequences)
    seqs = df[(df.dataset == dataset) & (df.source == "measured")].sequence.unique()
    return sorted(seqs)


def _datasets_in(df: pd.DataFrame, variant: str) -> list[str]:
    present = set(df[df.source == "measured"].dataset)
    if variant == "real":
        present |= set(DATASETS)
    return [d for d in DATASETS if d in present] + sorted(present - set(DATASETS))


def _label(method: str, source: str, marks: str = "") -> str:
    return f"{method} (published)" if source == "published" else method + marks


def _row(method: str, source: str, sub: pd.DataFrame, cells: list, v1: list, legend: ProtocolLegend) -> Row:
    if source == "published":
        return Row(_label(method, source), cells, None)
    labels = sorted({x for x in sub.protocol if x})
    return Row(_label(method, source, legend.marks(labels)), cells, float(sub.seconds.mean()), v1,
               " | ".join(labels))


def _sorted(rows: list[Row]) -> list[Row]:
    return sorted(rows, key=lambda r: (r.label.endswith("(published)"), r.label))


def main_table(df: pd.DataFrame, variant: str) -> Table:
    datasets = _datasets_in(df, variant)
    groups = [DATASETS[d].display_name if d in DATASETS else d for d in datasets]
    rows, notes, legend = [], [], ProtocolLegend()
    for (method, source), sub in df.groupby(["method", "source"], sort=True):
        cells: list[float | None] = []
        v1: list[float | None] = []
        for d in datasets:
            dsub = sub[sub.dataset == d]
            if source == "published":
                avg = dsub[dsub.sequence == "_average"]
                cells += [float(avg.miou.iloc[0]), float(avg.macc.iloc[0])] if len(avg) else [None, None]
                v1 += [None, None]
                continue
            expected = _expected_sequences(df, variant, d)
            have = set(dsub.sequence)
            if expected and set(expected) <= have:
                dsub = dsub[dsub.sequence.isin(expected)]
                cells += [_mean(dsub.miou), _mean(dsub.macc)]
                v1 += [_mean(dsub.miou_v1), _mean(dsub.macc_v1)]
            else:
                cells += [None, None]
                v1 += [None, None]
                if have:
                    notes.append(f"{method} on {d}: {len(have & set(expected))}/{len(expected)} "
                                 "sequences run, no average")
        rows.append(_row(method, source, sub, cells, v1, legend))
    notes = legend.notes() + notes + [METRIC_NOTE]
    if variant == "real":
        notes.append(PUBLISHED_NOTE)
    title = f"Segmentation in novel views ({variant} data): mIoU / mAcc per benchmark"
    return Table(title, groups, _sorted(rows), notes)


def _mean(col: pd.Series) -> float | None:
    vals = col.dropna()
    return float(vals.mean()) if len(vals) == len(col) and len(col) else None


def sequence_table(df: pd.DataFrame, variant: str, dataset: str) -> Table:
    seqs = _expected_sequences(df, variant, dataset)
    rows, legend = [], ProtocolLegend()
    for (method, source), sub in df[df.dataset == dataset].groupby(["method", "source"]):
        cells: list[float | None] = []
        v1: list[float | None] = []
        for s in seqs:
            hit = sub[sub.sequence == s]
            cells += [_value(hit.miou), _value(hit.macc)]
            v1 += [_value(hit.miou_v1), _value(hit.macc_v1)]
        if all(c is None for c in cells):
            continue
        rows.append(_row(method, source, sub, cells, v1, legend))
    name = DATASETS[dataset].display_name if dataset in DATASETS else dataset
    return Table(f"{name} per sequence ({variant} data)", seqs, _sorted(rows), legend.notes() + [METRIC_NOTE])


def _value(col: pd.Series) -> float | None:
    return float(col.iloc[0]) if len(col) and pd.notna(col.iloc[0]) else None


def build_tables(records: list[dict], variant: str, published: bool = True) -> list[Table]:
    """Main table then one per-sequence table per dataset with measured results. ``records``:
    the chosen runs, one per (method, dataset, sequence) (``benchmark.runs.one_run_per_row``)."""
    df = measured_frame([r for r in records if r["variant"] == variant])
    if variant == "real" and published:
        pub = published_frame()
        df = pd.concat([df, pub[df.columns]], ignore_index=True) if len(df) else pub[df.columns]
    if not len(df):
        return []
    tables = [main_table(df, variant)]
    for d in _datasets_in(df, variant):
        if (df[(df.dataset == d)].source == "measured").any():
            tables.append(sequence_table(df, variant, d))
    return tables


# -- rendering -------------------------------------------------------------------------------
def _fmt(x: float | None) -> str:
    return "—" if x is None else f"{x:.4f}"


def _fmt_time(x: float | None) -> str:
    return "—" if x is None or math.isnan(x) else f"{x:.1f}"


def render(table: Table, fmt: str) -> str:
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    return {"markdown": _markdown, "latex": _latex, "csv": _csv, "html": _html}[fmt](table)


def _cells(table: Table, bold: callable) -> list[tuple[str, list[str], str]]:
    best = table.best()
    out = []
    for label, cells, secs, v1, _ in table.rows:
        v1 = v1 or [None] * len(cells)
        txt = []
        for i, v in enumerate(cells):
            t = bold(_fmt(v)) if v is not None and v == best[i] else _fmt(v)
            if v is not None and v1[i] is not None and _fmt(v1[i]) != _fmt(v):
                t += f" (v1 {_fmt(v1[i])})"
            txt.append(t)
        out.append((label, txt, _fmt_time(secs)))
    return out


def _markdown(t: Table) -> str:
    head = ["method"] + [f"{g} mIoU" if i % 2 == 0 else f"{g} mAcc"
                         for g in t.groups for i in range(2)] + ["s/seq"]
    lines = [f"### {t.title}", "", "| " + " | ".join(head) + " |",
             "|" + "|".join(["---"] + ["---:"] * (len(head) - 1)) + "|"]
    for label, cells, secs in _cells(t, lambda s: f"**{s}**"):
        lines.append("| " + " | ".join([label] + cells + [secs]) + " |")
    lines += [""] + [f"- {n}" for n in t.notes]
    return "\n".join(lines).rstrip() + "\n"


def _latex(t: Table) -> str:
    esc = lambda s: s.replace("_", r"\_").replace("%", r"\%")
    lines = [r"\begin{table}[t]", r"\centering", r"\caption{" + esc(t.title) + "}",
             r"\begin{tabular}{l" + "cc" * len(t.groups) + "r}", r"\toprule",
             "Method & " + " & ".join(r"\multicolumn{2}{c}{" + esc(g) + "}" for g in t.groups)
             + r" & Time \\",
             " & " + " & ".join(["mIoU & mAcc"] * len(t.groups)) + r" & s/seq \\", r"\midrule"]
    for label, cells, secs in _cells(t, lambda s: r"\textbf{" + s + "}"):
        lines.append(" & ".join([esc(label)] + cells + [secs]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    if t.notes:  # protocol footnotes and the metric note
        lines += [r"\par\footnotesize"] + [esc(n) + r"\\" for n in t.notes]
    lines += [r"\end{table}"]
    return "\n".join(lines) + "\n"


def _csv(t: Table) -> str:
    rows = []
    for label, cells, secs, v1, protocol_text in t.rows:
        row = {"table": t.title, "method": label}
        v1 = v1 or [None] * len(cells)
        for i, g in enumerate(t.groups):
            row[f"{g}_miou"], row[f"{g}_macc"] = cells[2 * i], cells[2 * i + 1]
            row[f"{g}_miou_v1"], row[f"{g}_macc_v1"] = v1[2 * i], v1[2 * i + 1]
        row["seconds_per_sequence"] = secs
        row["protocol"] = protocol_text
        rows.append(row)
    buf = io.StringIO()
    pd.DataFrame(rows).to_csv(buf, index=False)
    return buf.getvalue()


def _html(t: Table) -> str:
    e = html.escape
    head = "".join(f'<th colspan="2">{e(g)}</th>' for g in t.groups)
    sub = "".join("<th>mIoU</th><th>mAcc</th>" for _ in t.groups)
    body = "".join(
        "<tr><td>" + e(label) + "</td>" + "".join(f"<td>{c}</td>" for c in cells)
        + f"<td>{secs}</td></tr>"
        for label, cells, secs in _cells(t, lambda s: f"<b>{s}</b>")
    )
    notes = "".join(f"<li>{e(n)}</li>" for n in t.notes)
    return (f"<h3>{e(t.title)}</h3><table><thead><tr><th rowspan=2>method</th>{head}"
            f"<th>s/seq</th></tr><tr>{sub}<th></th></tr></thead><tbody>{body}</tbody></table>"
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
