"""``trase-bench report``: one self-contained HTML page per run."""

from __future__ import annotations

from pathlib import Path

import click

from benchmark.errors import UserError
from benchmark.results.report import make_report


@click.command()
@click.option("--method", required=True)
@click.option("--dataset", required=True)
@click.option("--sequence", required=True)
@click.option("--name", default=None, help="The run's name (see `trase-bench runs`); default: the main run.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="runs", show_default=True,
              help="The --out directory of `trase-bench run`.")
def report(method: str, dataset: str, sequence: str, name: str | None, out_dir: str) -> None:
    """Write report.html (test views with predicted and ground-truth masks, per-frame IoU,
    clusters, stage timings, config) next to the run's results.json."""
    from benchmark.results.runs import load_run, newest_per_seed

    seq_dir = Path(out_dir) / method / dataset / sequence
    if name is not None:
        run = load_run(seq_dir / name)
    else:
        runs = [d for d in sorted(seq_dir.glob("*")) if (d / "results.json").is_file()] if seq_dir.is_dir() else []
        mains = [r for r in (load_run(d) for d in runs) if r["run"]["kind"] == "main"]
        if not mains:
            raise UserError(f"{seq_dir}: no main run of {method} on {dataset}/{sequence}; run "
                            f"`trase-bench run --method {method} --dataset {dataset}` or pass --name "
                            f"({', '.join(d.name for d in runs) or 'no runs there'})")
        if len({r["run"]["group"] for r in mains}) > 1:
            raise UserError(f"{seq_dir}: {len(mains)} main runs with different configs "
                            f"({', '.join(Path(r['_dir']).name for r in mains)}); choose one with --name")
        # the lowest seed (its siblings' scores are in the report), newest if rerun
        run = newest_per_seed(mains)[0]
    click.echo(f"wrote {make_report(Path(run['_dir']))}")

