"""``trase-bench report``: one self-contained HTML page per run."""

from __future__ import annotations

from pathlib import Path

import click
from click.core import ParameterSource

from benchmark.commands import old_spelling
from benchmark.errors import UserError
from benchmark.results.report import make_report
from benchmark.scene.render import selection_clip


@click.command()
@old_spelling("--out", "--runs")
@click.option("--run", "run_dir", type=click.Path(exists=True), metavar="DIR",
              help="The run (its directory or its results.json), instead of --method/--dataset/--sequence.")
@click.option("--method", default=None)
@click.option("--dataset", default=None)
@click.option("--sequence", default=None)
@click.option("--name", default=None, help="The run's name (see `trase-bench runs`); default: the main run "
              "(or the external one).")
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default="runs", show_default=True,
              help="The folder of runs that --method/--dataset/--sequence/--name look in.")
def report(run_dir: str | None, method: str | None, dataset: str | None, sequence: str | None, name: str | None,
           runs_dir: str) -> None:
    """Write report.html (test views with predicted and ground-truth masks, per-frame IoU,
    clusters, stage timings, config) next to the run's results.json.

    The run: --run DIR, or --method, --dataset and --sequence (with --name, else the main
    run) under --runs.
    """
    from benchmark.results.runs import load_run, newest_per_seed

    named = {"--method": method, "--dataset": dataset, "--sequence": sequence}
    if run_dir is not None:
        given = [k for k, v in {**named, "--name": name}.items() if v is not None]
        if click.get_current_context().get_parameter_source("runs_dir") is ParameterSource.COMMANDLINE:
            given.append("--runs")
        if given:
            raise click.UsageError(f"--run names the run; leave out {', '.join(given)}")
        run = load_run(Path(run_dir))
        click.echo(f"wrote {make_report(Path(run['_dir']), selection_clip)}")
        return
    missing = [k for k, v in named.items() if v is None]
    if missing:
        raise click.UsageError(f"say which run: --run DIR, or --method, --dataset and --sequence "
                               f"(missing {', '.join(missing)})")
    seq_dir = Path(runs_dir) / method / dataset / sequence
    if name is not None:
        run = load_run(seq_dir / name)
    else:
        runs = [d for d in sorted(seq_dir.glob("*")) if (d / "results.json").is_file()] if seq_dir.is_dir() else []
        mains = [r for r in (load_run(d) for d in runs) if r["run"]["kind"] in ("main", "external")]
        if not mains:
            raise UserError(f"{seq_dir}: no main run of {method} on {dataset}/{sequence}; run "
                            f"`trase-bench run --method {method} --dataset {dataset}` or pass --name "
                            f"({', '.join(d.name for d in runs) or 'no runs there'})")
        if len({r["run"]["group"] for r in mains}) > 1:
            raise UserError(f"{seq_dir}: {len(mains)} main runs with different configs "
                            f"({', '.join(Path(r['_dir']).name for r in mains)}); choose one with --name")
        # the lowest seed (its siblings' scores are in the report), newest if rerun
        run = newest_per_seed(mains)[0]
    click.echo(f"wrote {make_report(Path(run['_dir']), selection_clip)}")
