"""Leaderboards rendered from runs (and the paper's published numbers), never typed.

Layout follows the paper's Table 1: one row per method, a (mIoU, mAcc) column pair per
benchmark, the best value of each column in bold, and a time column. Per-sequence tables
follow the supplementary. Rules:

* the caller chooses the runs (``benchmark.results.runs``: by default each method's main run and
  the external runs), and a cell is one run: two configs for one (method, dataset, sequence) are refused before this;
* every measured row carries its protocol (geometry, features preset, masks, prompts, render
  rule, metric) as a footnote marker; external predictions (``trase-bench evaluate``) say that
  their prompts and geometry were not the benchmark's, and have no time;
* cells use the official metric, the one the published rows were made with; the project's
  ``v1`` is shown beside a cell where it differs;
* real and synthetic results never share a table (``variant``);
* published numbers appear only beside real results, as separate rows labelled
  ``(published)``, with the supplementary's own average;
* a dataset average is shown only when the method ran every sequence of that dataset
  (real: the paper's list; synthetic: every synthetic sequence any method ran);
* a config run with several seeds is one row: the mean over seeds, ± the standard deviation
  (sample, ddof 1) and the seed count; a cell within the spread of its column's best is marked
  ``≈`` (the order of the two is not established).
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
from benchmark.results.record import total_seconds
from benchmark.results.runs import ProtocolLegend, protocol, protocol_label

FORMATS = ("markdown", "latex", "csv", "html")
PUBLISHED_NOTE = (
    "Published rows: the TRASE paper's supplementary per-sequence tables and their Average "
    "column (OpenGaussian on HyperNeRF-Mask: Table 1 says 0.6311/0.9411, the supplementary "
    "0.6531/0.9480; SA4D on Neu3D-Mask mAcc: Table 1 0.9391, supplementary 0.9931)."
)
METRIC_NOTE = ("Measured cells: the official metric (the public evaluation script's rules, which the "
               "paper's numbers were made with); the project's v1 metric in brackets where it differs.")


SPREAD_NOTE = ("± : standard deviation over run seeds (sample, ddof 1); seeds: how many. ≈ : within the "
               "spread of the column's best (|difference| < the larger of the two deviations), so the "
               "order of the two is not established.")


class Row(NamedTuple):
    label: str  # method, its protocol marks, or "(published)"
    cells: list[float | None]  # [miou, macc] * groups, official metric (mean over seeds)
    seconds: float | None  # per sequence
    v1: list[float | None] | None = None  # the v1 metric's cells (None: published row)
    protocol: str = ""  # the protocol label(s) behind the marks
    spread: list[float | None] | None = None  # std over seeds per cell (None: one seed)
    seeds: int | None = None  # seeds per cell (the fewest; None: published row)


@dataclasses.dataclass
class Table:
    title: str
    groups: list[str]  # one per column pair (dataset or sequence)
    rows: list[Row]
    notes: list[str] = dataclasses.field(default_factory=list)

    def best(self) -> list[float | None]:
        n = 2 * len(self.groups)
        cols = [[r.cells[i] for r in self.rows if r.cells[i] is not None] for i in range(n)]
        return [max(c) if c else None for c in cols]

    def has_seeds(self) -> bool:
        return any(r.seeds is not None and r.seeds > 1 for r in self.rows)

    def within_spread(self, row: Row, i: int, best: float | None) -> bool:
        """Whether cell i of ``row`` is within the spread of the column's ``best``."""
        spreads = [row.spread[i] if row.spread else None]
        spreads += [r.spread[i] for r in self.rows if r.spread and r.cells[i] == best]
        return within_spread(row.cells[i], best, spreads)


def within_spread(value: float | None, best: float | None, spreads) -> bool:
    """Not the best, but closer to it than the larger of ``spreads`` (std over seeds of the
    two; None / NaN ignored): their order is not established. Tables mark such cells ≈."""
    spreads = [x for x in spreads if x is not None and not math.isnan(x)]
    if value is None or best is None or value == best or not spreads:
        return False
    return best - value < max(spreads)


# -- data ------------------------------------------------------------------------------------
def measured_frame(records: list[dict]) -> pd.DataFrame:
    """One row per run: official metric (``miou``, ``macc``), v1 beside, protocol label."""
    rows = [
        {
            "variant": r["variant"],
            "dataset": r["dataset"],
            "sequence": r["sequence"],
            "method": r["method"],
            "seed": r["run"]["seed"],
            "miou": r["metrics"]["official"]["miou"],
            "macc": r["metrics"]["official"]["macc"],
            "miou_v1": r["metrics"]["miou"],
            "macc_v1": r["metrics"]["macc"],
            "seconds": math.nan if r["run"]["kind"] == "external" else total_seconds(r),  # not timed here
            "source": "measured",
            "protocol": protocol_label(protocol(r)),
        }
        for r in records
    ]
    return pd.DataFrame(rows, columns=COLUMNS)


COLUMNS = ["variant", "dataset", "sequence", "method", "seed", "miou", "macc", "miou_v1", "macc_v1", "seconds",
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
    df["seed"] = -1
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


def _row(method: str, source: str, sub: pd.DataFrame, cells: list, v1: list | None,
         spread: list | None = None, seeds: int | None = None, legend: ProtocolLegend | None = None) -> Row:
    if source == "published":
        return Row(_label(method, source), cells, None)
    labels = sorted({x for x in sub.protocol if x})
    return Row(_label(method, source, legend.marks(labels)), cells, float(sub.seconds.mean()), v1,
               " | ".join(labels), spread, seeds)


def _over_seeds(sub: pd.DataFrame, sequences: list[str], col: str) -> tuple[float | None, float | None, int]:
    """Mean over ``sequences`` of one metric, for each seed run on all of them -> (mean over
    those seeds, their std (ddof 1; None for one seed), seed count). (None, None, 0) when a
    sequence lacks a value."""
    have = sub[sub.sequence.isin(sequences)]
    per_seed = have.groupby("seed")[col].agg(["mean", "count"])
    per_seed = per_seed[per_seed["count"] == len(sequences)]["mean"]
    if not len(per_seed) or per_seed.isna().any():
        return None, None, 0
    spread = float(per_seed.std(ddof=1)) if len(per_seed) > 1 else None
    return float(per_seed.mean()), spread, len(per_seed)


def _sorted(rows: list[Row]) -> list[Row]:
    return sorted(rows, key=lambda r: (r.label.endswith("(published)"), r.label))


def main_table(df: pd.DataFrame, variant: str) -> Table:
    datasets = _datasets_in(df, variant)
    groups = [DATASETS[d].display_name if d in DATASETS else d for d in datasets]
    rows, notes, legend = [], [], ProtocolLegend()
    for (method, source), sub in df.groupby(["method", "source"], sort=True):
        if source == "published":
            cells: list[float | None] = []
            for d in datasets:
                avg = sub[(sub.dataset == d) & (sub.sequence == "_average")]
                cells += [float(avg.miou.iloc[0]), float(avg.macc.iloc[0])] if len(avg) else [None, None]
            rows.append(_row(method, source, sub, cells, None, legend=legend))
            continue
        spans = []  # per dataset: (its runs, the sequences averaged); runs None: not all ran
        for d in datasets:
            expected = _expected_sequences(df, variant, d)
            dsub = sub[sub.dataset == d]
            have = set(dsub.sequence)
            complete = bool(expected) and set(expected) <= have
            spans.append((dsub if complete else None, expected))
            if have and not complete:
                notes.append(f"{method} on {d}: {len(have & set(expected))}/{len(expected)} "
                             "sequences run, no average")
        rows.append(_row(method, source, sub, *_measured(spans), legend=legend))
    notes = legend.notes() + notes + [METRIC_NOTE] + ([SPREAD_NOTE] if _any_seeds(rows) else [])
    if variant == "real":
        notes.append(PUBLISHED_NOTE)
    title = f"Segmentation in novel views ({variant} data): mIoU / mAcc per benchmark"
    return Table(title, groups, _sorted(rows), notes)


def _measured(spans: list[tuple[pd.DataFrame | None, list[str]]]) -> tuple[list, list, list | None, int]:
    """Cells of a measured row, one (mIoU, mAcc) pair per (runs, sequences) span (runs None:
    no cell) -> (cells, v1 cells, spread over seeds, seeds: the fewest behind a cell)."""
    cells, v1, spread, counts = [], [], [], []
    for part, sequences in spans:
        if part is None:
            cells += [None, None]
            v1 += [None, None]
            spread += [None, None]
            continue
        for col in ("miou", "macc"):
            mean, std, n = _over_seeds(part, sequences, col)
            cells.append(mean)
            spread.append(std)
            counts.append(n)
        v1 += [_over_seeds(part, sequences, "miou_v1")[0], _over_seeds(part, sequences, "macc_v1")[0]]
    return cells, v1, spread or None, min((c for c in counts if c), default=1)


def _any_seeds(rows: list[Row]) -> bool:
    return any(r.seeds and r.seeds > 1 for r in rows)


def sequence_table(df: pd.DataFrame, variant: str, dataset: str) -> Table:
    seqs = _expected_sequences(df, variant, dataset)
    rows, legend = [], ProtocolLegend()
    for (method, source), sub in df[df.dataset == dataset].groupby(["method", "source"]):
        if source == "published":
            cells = [x for q in seqs for x in (_value(sub[sub.sequence == q].miou), _value(sub[sub.sequence == q].macc))]
            row = _row(method, source, sub, cells, None, legend=legend)
        else:
            row = _row(method, source, sub, *_measured([(sub, [q]) for q in seqs]), legend=legend)
        if any(c is not None for c in row.cells):
            rows.append(row)
    name = DATASETS[dataset].display_name if dataset in DATASETS else dataset
    notes = legend.notes() + [METRIC_NOTE] + ([SPREAD_NOTE] if _any_seeds(rows) else [])
    return Table(f"{name} per sequence ({variant} data)", seqs, _sorted(rows), notes)


def _value(col: pd.Series) -> float | None:
    return float(col.iloc[0]) if len(col) and pd.notna(col.iloc[0]) else None


def build_tables(records: list[dict], variant: str, published: bool = True) -> list[Table]:
    """Main table then one per-sequence table per dataset with measured results. ``records``:
    the chosen runs, one config per (method, dataset, sequence), one run per seed
    (``benchmark.results.runs.one_config_per_row``)."""
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


def _cells(table: Table, bold: callable, pm: str = "±", approx: str = "≈") -> list[tuple[str, list[str], str]]:
    """(label, cell texts, time text [, seeds text]) per row: the mean (bold if best), ± its
    spread, ≈ when within the spread of the best, the v1 metric where it differs."""
    best = table.best()
    seeds_col = table.has_seeds()
    out = []
    for row in table.rows:
        v1 = row.v1 or [None] * len(row.cells)
        txt = []
        for i, v in enumerate(row.cells):
            t = bold(_fmt(v)) if v is not None and v == best[i] else _fmt(v)
            sd = row.spread[i] if row.spread else None
            if v is not None and sd is not None:
                t += f" {pm} {_fmt(sd)}"
            if table.within_spread(row, i, best[i]):
                t = f"{approx}{t}"
            if v is not None and v1[i] is not None and _fmt(v1[i]) != _fmt(v):
                t += f" (v1 {_fmt(v1[i])})"
            txt.append(t)
        entry = (row.label, txt, _fmt_time(row.seconds))
        if seeds_col:
            entry += ("—" if row.seeds is None else str(row.seeds),)
        out.append(entry)
    return out


def _markdown(t: Table) -> str:
    head = ["method"] + [f"{g} mIoU" if i % 2 == 0 else f"{g} mAcc"
                         for g in t.groups for i in range(2)] + ["s/seq"] + (["seeds"] if t.has_seeds() else [])
    lines = [f"### {t.title}", "", "| " + " | ".join(head) + " |",
             "|" + "|".join(["---"] + ["---:"] * (len(head) - 1)) + "|"]
    for label, cells, secs, *seeds in _cells(t, lambda s: f"**{s}**"):
        lines.append("| " + " | ".join([label] + cells + [secs] + seeds) + " |")
    lines += [""] + [f"- {n}" for n in t.notes]
    return "\n".join(lines).rstrip() + "\n"


def _latex(t: Table) -> str:
    esc = lambda s: s.replace("_", r"\_").replace("%", r"\%")
    extra = t.has_seeds()
    lines = [r"\begin{table}[t]", r"\centering", r"\caption{" + esc(t.title) + "}",
             r"\begin{tabular}{l" + "cc" * len(t.groups) + "r" + ("r" if extra else "") + "}", r"\toprule",
             "Method & " + " & ".join(r"\multicolumn{2}{c}{" + esc(g) + "}" for g in t.groups)
             + r" & Time" + (" & Seeds" if extra else "") + r" \\",
             " & " + " & ".join(["mIoU & mAcc"] * len(t.groups)) + r" & s/seq" + (" & " if extra else "")
             + r" \\", r"\midrule"]
    for label, cells, secs, *seeds in _cells(t, lambda s: r"\textbf{" + s + "}", pm=r"$\pm$", approx=r"$\approx$"):
        lines.append(" & ".join([esc(label)] + cells + [secs] + seeds) + r" \\")
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
        for i, g in enumerate(t.groups):
            row[f"{g}_miou"], row[f"{g}_macc"] = r.cells[2 * i], r.cells[2 * i + 1]
            row[f"{g}_miou_std"], row[f"{g}_macc_std"] = spread[2 * i], spread[2 * i + 1]
            row[f"{g}_miou_v1"], row[f"{g}_macc_v1"] = v1[2 * i], v1[2 * i + 1]
        row["seconds_per_sequence"] = r.seconds
        row["seeds"] = r.seeds
        row["protocol"] = r.protocol
        rows.append(row)
    buf = io.StringIO()
    pd.DataFrame(rows).to_csv(buf, index=False)
    return buf.getvalue()


def _html(t: Table) -> str:
    e = html.escape
    extra = t.has_seeds()
    head = "".join(f'<th colspan="2">{e(g)}</th>' for g in t.groups)
    sub = "".join("<th>mIoU</th><th>mAcc</th>" for _ in t.groups)
    body = "".join(
        "<tr><td>" + e(label) + "</td>" + "".join(f"<td>{c}</td>" for c in cells)
        + f"<td>{secs}</td>" + "".join(f"<td>{x}</td>" for x in seeds) + "</tr>"
        for label, cells, secs, *seeds in _cells(t, lambda s: f"<b>{s}</b>")
    )
    notes = "".join(f"<li>{e(n)}</li>" for n in t.notes)
    seeds_head = "<th rowspan=2>seeds</th>" if extra else ""
    return (f"<h3>{e(t.title)}</h3><table><thead><tr><th rowspan=2>method</th>{head}"
            f"<th>s/seq</th>{seeds_head}</tr><tr>{sub}<th></th></tr></thead><tbody>{body}</tbody></table>"
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
