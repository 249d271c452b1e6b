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
import math
from importlib import resources
from typing import NamedTuple

import pandas as pd

from benchmark.datasets import DATASETS
from benchmark.results.record import total_seconds
from benchmark.results.runs import ProtocolLegend, protocol, protocol_label

PUBLISHED_NOTE = (
    "Published rows: the TRASE paper's supplementary per-sequence tables and their Average "
    "column (OpenGaussian on HyperNeRF-Mask: Table 1 says 0.6311/0.9411, the supplementary "
    "0.6531/0.9480; SA4D on Neu3D-Mask mAcc: Table 1 0.9391, supplementary 0.9931). Their prompts: a "
    "person's clicks in the rendered novel views, as many as the person chose (the paper)."
)
METRIC_NOTE = ("Measured cells: the official metric (the public evaluation script's rules, which the "
               "paper's numbers were made with); the project's v1 metric in brackets where it differs.")


SPREAD_NOTE = ("± : standard deviation over run seeds (sample, ddof 1); seeds: how many. ≈ : within the "
               "spread of the column's best (|difference| < the larger of the two deviations), so the "
               "order of the two is not established.")


CLICK_COLUMNS = ("miou1", "noc85", "noc90")  # measured_frame's columns of the corrective protocol
CLICK_NAMES = ("mIoU@1", "NoC@85", "NoC@90")
CLICK_NOTE = ("mIoU@1: official mIoU after one click per object of interest; NoC@85 / NoC@90: clicks the robot "
              "user needed to reach that mIoU over the test frames (its first clicks + budget + 1 where it never "
              "did; fewer is better); means over sequences, ± over seeds.")


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
    groups: list[str]  # one per group of columns (dataset or sequence)
    rows: list[Row]
    notes: list[str] = dataclasses.field(default_factory=list)
    columns: tuple[str, ...] = ("mIoU", "mAcc")  # per group
    lower_is_better: tuple[str, ...] = ()  # columns whose best is the least (clicks)
    timed: bool = True  # a seconds-per-sequence column

    def column(self, i: int) -> str:
        """The name of cell i's column."""
        return self.columns[i % len(self.columns)]

    def best(self) -> list[float | None]:
        n = len(self.columns) * len(self.groups)
        cols = [[r.cells[i] for r in self.rows if r.cells[i] is not None] for i in range(n)]
        return [None if not c else min(c) if self.column(i) in self.lower_is_better else max(c)
                for i, c in enumerate(cols)]

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
    return abs(best - value) < max(spreads)  # the best is the most, or the least (clicks)


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
            **clicks_of(r),
        }
        for r in records
    ]
    return pd.DataFrame(rows, columns=COLUMNS)


COLUMNS = ["variant", "dataset", "sequence", "method", "seed", "miou", "macc", "miou_v1", "macc_v1", "seconds",
           "source", "protocol", *CLICK_COLUMNS]


def clicks_of(record: dict) -> dict:
    """The corrective protocol's figures of a run (benchmark.pipeline.corrective): mIoU@1 (one
    click per object), NoC@85, NoC@90; NaN where the run had its first clicks alone."""
    c = record.get("corrective")
    if not c:
        return dict.fromkeys(CLICK_COLUMNS, math.nan)
    return {"miou1": c["curve"][0]["miou"], "noc85": float(c["noc@85"]), "noc90": float(c["noc@90"])}


def published_frame() -> pd.DataFrame:
    """The paper's per-sequence numbers (package data); ``_average`` rows are its averages."""
    path = resources.files("benchmark") / "data" / "published" / "trase_paper_per_sequence.csv"
    with path.open() as f:
        df = pd.read_csv(f)
    df["variant"] = "real"
    df["source"] = "published"
    df["seconds"] = math.nan
    df["miou_v1"] = df["macc_v1"] = math.nan
    for col in CLICK_COLUMNS:  # no robot user: the published numbers came from a person's clicks
        df[col] = math.nan
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


def _measured(spans: list[tuple[pd.DataFrame | None, list[str]]], cols=("miou", "macc"),
              v1_cols=("miou_v1", "macc_v1")) -> tuple[list, list, list | None, int]:
    """Cells of a measured row, one cell per column of ``cols`` per (runs, sequences) span (runs
    None: no cell) -> (cells, v1 cells (``v1_cols``, None each where empty), spread over seeds,
    seeds: the fewest behind a cell)."""
    cells, v1, spread, counts = [], [], [], []
    for part, sequences in spans:
        if part is None:
            cells += [None] * len(cols)
            v1 += [None] * len(cols)
            spread += [None] * len(cols)
            continue
        for col in cols:
            mean, std, n = _over_seeds(part, sequences, col)
            cells.append(mean)
            spread.append(std)
            counts.append(n)
        v1 += [_over_seeds(part, sequences, c)[0] for c in v1_cols] if v1_cols else [None] * len(cols)
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


def clicks_table(df: pd.DataFrame, variant: str, dataset: str | None = None) -> Table | None:
    """The corrective protocol's figures (CLICK_NAMES) of the measured methods that have them:
    per benchmark (``dataset`` None; a method that ran every sequence of it) or per sequence of
    ``dataset``; None where no run corrected."""
    have = df[(df.source == "measured") & df.miou1.notna()]
    if dataset is not None:
        have = have[have.dataset == dataset]
    if not len(have):
        return None
    if dataset is None:
        keys = _datasets_in(have, "synthetic")  # only those measured
        groups = [DATASETS[d].display_name if d in DATASETS else d for d in keys]
        spans_of = lambda sub: [(sub[sub.dataset == d] if set(_expected_sequences(df, variant, d))
                                 <= set(sub[sub.dataset == d].sequence) else None, _expected_sequences(df, variant, d))
                                for d in keys]
        title = f"Clicks ({variant} data): mIoU@1 and clicks to reach mIoU 0.85 / 0.90 per benchmark"
    else:
        groups = _expected_sequences(df, variant, dataset)
        spans_of = lambda sub: [(sub, [q]) for q in groups]
        name = DATASETS[dataset].display_name if dataset in DATASETS else dataset
        title = f"{name} clicks per sequence ({variant} data)"
    rows, legend = [], ProtocolLegend()
    for method, sub in have.groupby("method", sort=True):
        row = _row(method, "measured", sub, *_measured(spans_of(sub), CLICK_COLUMNS, ()), legend=legend)
        rows.append(row._replace(seconds=None))
    notes = legend.notes() + [CLICK_NOTE] + ([SPREAD_NOTE] if _any_seeds(rows) else [])
    return Table(title, groups, _sorted(rows), notes, CLICK_NAMES, CLICK_NAMES[1:], timed=False)


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
    tables = [main_table(df, variant)] + [t for t in [clicks_table(df, variant)] if t]
    for d in _datasets_in(df, variant):
        if (df[(df.dataset == d)].source == "measured").any():
            tables += [sequence_table(df, variant, d)] + [t for t in [clicks_table(df, variant, d)] if t]
    return tables
