"""Leaderboards rendered from results files (and the paper's published numbers), never typed.

Layout follows the paper's Table 1: one row per method, a (mIoU, mAcc) column pair per
benchmark, the best value of each column in bold, and a time column. Per-sequence tables
follow the supplementary. Rules:

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

import pandas as pd

from benchmark.datasets import DATASETS
from benchmark.results import total_seconds

FORMATS = ("markdown", "latex", "csv", "html")
PUBLISHED_NOTE = (
    "Published rows: the TRASE paper's supplementary per-sequence tables and their Average "
    "column (OpenGaussian on HyperNeRF-Mask: Table 1 says 0.6311/0.9411, the supplementary "
    "0.6531/0.9480; SA4D on Neu3D-Mask mAcc: Table 1 0.9391, supplementary 0.9931)."
)


@dataclasses.dataclass
class Table:
    title: str
    groups: list[str]  # one per column pair (dataset or sequence)
    rows: list[tuple[str, list[float | None], float | None]]  # label, [miou, macc]*groups, s/seq
    notes: list[str] = dataclasses.field(default_factory=list)

    def best(self) -> list[float | None]:
        n = 2 * len(self.groups)
        cols = [[r[1][i] for r in self.rows if r[1][i] is not None] for i in range(n)]
        return [max(c) if c else None for c in cols]


# -- data ------------------------------------------------------------------------------------
def measured_frame(records: list[dict]) -> pd.DataFrame:
    rows = [
        {
            "variant": r["variant"],
            "dataset": r["dataset"],
            "sequence": r["sequence"],
            "method": r["method"],
            "miou": r["metrics"]["miou"],
            "macc": r["metrics"]["macc"],
            "seconds": total_seconds(r),
            "source": "measured",
        }
        for r in records
    ]
    cols = ["variant", "dataset", "sequence", "method", "miou", "macc", "seconds", "source"]
    return pd.DataFrame(rows, columns=cols)


def published_frame() -> pd.DataFrame:
    """The paper's per-sequence numbers (package data); ``_average`` rows are its averages."""
    path = resources.files("benchmark") / "data" / "published" / "trase_paper_per_sequence.csv"
    with path.open() as f:
        df = pd.read_csv(f)
    df["variant"] = "real"
    df["source"] = "published"
    df["seconds"] = math.nan
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


def _label(method: str, source: str) -> str:
    return f"{method} (published)" if source == "published" else method


def main_table(df: pd.DataFrame, variant: str) -> Table:
    datasets = _datasets_in(df, variant)
    groups = [DATASETS[d].display_name if d in DATASETS else d for d in datasets]
    rows, notes = [], []
    for (method, source), sub in df.groupby(["method", "source"], sort=True):
        cells: list[float | None] = []
        for d in datasets:
            dsub = sub[sub.dataset == d]
            if source == "published":
                avg = dsub[dsub.sequence == "_average"]
                cells += [float(avg.miou.iloc[0]), float(avg.macc.iloc[0])] if len(avg) else [None, None]
                continue
            expected = _expected_sequences(df, variant, d)
            have = set(dsub.sequence)
            if expected and set(expected) <= have:
                dsub = dsub[dsub.sequence.isin(expected)]
                cells += [float(dsub.miou.mean()), float(dsub.macc.mean())]
            else:
                cells += [None, None]
                if have:
                    notes.append(f"{method} on {d}: {len(have & set(expected))}/{len(expected)} "
                                 "sequences run, no average")
        secs = None if source == "published" else float(sub.seconds.mean())
        rows.append((_label(method, source), cells, secs))
    rows.sort(key=lambda r: (r[0].endswith("(published)"), r[0]))
    if variant == "real":
        notes.append(PUBLISHED_NOTE)
    title = f"Segmentation in novel views ({variant} data): mIoU / mAcc per benchmark"
    return Table(title, groups, rows, notes)


def sequence_table(df: pd.DataFrame, variant: str, dataset: str) -> Table:
    seqs = _expected_sequences(df, variant, dataset)
    rows = []
    for (method, source), sub in df[df.dataset == dataset].groupby(["method", "source"]):
        cells: list[float | None] = []
        for s in seqs:
            hit = sub[sub.sequence == s]
            cells += [float(hit.miou.iloc[0]), float(hit.macc.iloc[0])] if len(hit) else [None, None]
        if all(c is None for c in cells):
            continue
        secs = None if source == "published" else float(sub.seconds.mean())
        rows.append((_label(method, source), cells, secs))
    rows.sort(key=lambda r: (r[0].endswith("(published)"), r[0]))
    name = DATASETS[dataset].display_name if dataset in DATASETS else dataset
    return Table(f"{name} per sequence ({variant} data)", seqs, rows)


def build_tables(records: list[dict], variant: str, published: bool = True) -> list[Table]:
    """Main table then one per-sequence table per dataset with measured results."""
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
    for label, cells, secs in table.rows:
        txt = [bold(_fmt(v)) if v is not None and v == best[i] else _fmt(v) for i, v in enumerate(cells)]
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
    esc = lambda s: s.replace("_", r"\_").replace("%", r"\%")  # noqa: E731
    lines = [r"\begin{table}[t]", r"\centering", r"\caption{" + esc(t.title) + "}",
             r"\begin{tabular}{l" + "cc" * len(t.groups) + "r}", r"\toprule",
             "Method & " + " & ".join(r"\multicolumn{2}{c}{" + esc(g) + "}" for g in t.groups)
             + r" & Time \\",
             " & " + " & ".join(["mIoU & mAcc"] * len(t.groups)) + r" & s/seq \\", r"\midrule"]
    for label, cells, secs in _cells(t, lambda s: r"\textbf{" + s + "}"):
        lines.append(" & ".join([esc(label)] + cells + [secs]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def _csv(t: Table) -> str:
    rows = []
    for label, cells, secs in t.rows:
        row = {"table": t.title, "method": label}
        for i, g in enumerate(t.groups):
            row[f"{g}_miou"], row[f"{g}_macc"] = cells[2 * i], cells[2 * i + 1]
        row["seconds_per_sequence"] = secs
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
