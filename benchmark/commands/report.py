"""``trase-bench report``: one self-contained HTML page per (method, dataset, sequence)."""

from __future__ import annotations

from pathlib import Path

import click

from benchmark.errors import UserError
from benchmark.report import make_report
from benchmark.results import results_path


@click.command()
@click.option("--method", required=True)
@click.option("--dataset", required=True)
@click.option("--sequence", required=True)
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="runs", show_default=True,
              help="The --out directory of `trase-bench run`.")
def report(method: str, dataset: str, sequence: str, out_dir: str) -> None:
    """Write report.html (test views with predicted and ground-truth masks, per-frame IoU,
    clusters, stage timings, config) next to the run's results.json."""
    path = results_path(Path(out_dir), method, dataset, sequence)
    if not path.exists():
        raise UserError(f"{path}: no results for {method} on {dataset}/{sequence}; "
                        f"run `trase-bench run --method {method} --dataset {dataset}` first")
    click.echo(f"wrote {make_report(path.parent)}")
