"""``trase-bench leaderboard``: tables rendered from chosen runs."""

from __future__ import annotations

from pathlib import Path

import click

from benchmark.commands import old_spelling
from benchmark.results.leaderboard_render import FORMATS, render_all


@click.command()
@old_spelling("--results", "--runs")
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default="runs",
              show_default=True, help="The folder of runs (searched recursively).")
@click.option("--run", "run_dirs", multiple=True, type=click.Path(),
              help="Use exactly these runs (a run directory or its results.json; repeatable) instead of "
                   "the main runs under --runs. See `trase-bench runs`.")
@click.option("--kind", "kinds", multiple=True, type=click.Choice(["main", "run", "ablation", "external"]),
              help="Kinds of run taken from --runs (repeatable; default: main, i.e. made with the "
                   "method's defaults, and external, scored by `trase-bench evaluate`). Ablation variants "
                   "enter only when asked for, one per row (several variants of one method: pick with --run).")
@click.option("--format", "fmt", type=click.Choice(FORMATS), default="markdown", show_default=True)
@click.option("--variant", type=click.Choice(["all", "synthetic", "real"]), default="all",
              show_default=True, help="Which data variant's tables to show.")
@click.option("--no-published", is_flag=True, help="Leave out the paper's published rows.")
@click.option("--out", type=click.Path(dir_okay=False), help="Write to a file instead of stdout.")
def leaderboard(runs_dir: str, run_dirs: tuple[str, ...], kinds: tuple[str, ...], fmt: str, variant: str,
                no_published: bool, out: str | None) -> None:
    """Leaderboard in the paper's Table 1 layout plus per-sequence tables.

    By default each method's main run under --runs (made without --set) and the external
    predictions scored by `trase-bench evaluate`; --run picks runs explicitly. Two runs with
    different configs for one method and sequence are refused. Every measured row names its
    protocol; cells use the official metric (v1 beside where it differs). Synthetic and real
    results are separate tables; published numbers are labelled rows beside real results only.
    """
    from benchmark.results.runs import (
        TABLE_KINDS,
        find_runs,
        load_run,
        one_config_per_row,
        select_runs,
    )

    warn = lambda m: click.echo(m, err=True)
    if run_dirs:
        if kinds:
            raise click.UsageError("--kind chooses runs under --runs; with --run the runs are given")
        records = [load_run(Path(p)) for p in run_dirs]
    else:
        found = find_runs(Path(runs_dir), warn=warn)
        records = select_runs(found, kinds or TABLE_KINDS)
        if not kinds:
            note_left_out(found, records, warn)
    records = one_config_per_row(records)
    variants = ("synthetic", "real") if variant == "all" else (variant,)
    text = render_all(records, fmt, variants=variants, published=not no_published)
    if not records:
        shown = "; showing the published rows only" if "real" in variants and not no_published else ""
        warn(f"note: no {'/'.join(kinds or TABLE_KINDS)} runs under {runs_dir}{shown}")
    if out:
        from benchmark.io import atomic_write_text

        atomic_write_text(out, text)
        click.echo(f"wrote {out}")
    else:
        click.echo(text, nl=False)


def note_left_out(found: list[dict], shown: list[dict], warn) -> None:
    """A note naming the methods whose runs under --runs the default tables leave out (runs
    made with --set: kind "run"), and how to show them."""
    shown_methods = {r["method"] for r in shown}
    left = sorted({r["method"] for r in found if r["run"]["kind"] == "run"} - shown_methods)
    if left:
        warn(f"note: not shown, every run made with --set (kind run): {', '.join(left)}; "
             "--kind run shows them, `trase-bench runs` lists them")
