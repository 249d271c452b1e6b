"""``trase-bench leaderboard``: tables rendered from results files."""

from __future__ import annotations

from pathlib import Path

import click

from benchmark.leaderboard import FORMATS, render_all
from benchmark.results import find_results


@click.command()
@click.option("--results", "results_dir", type=click.Path(file_okay=False), default="runs",
              show_default=True, help="Directory searched recursively for results.json.")
@click.option("--format", "fmt", type=click.Choice(FORMATS), default="markdown", show_default=True)
@click.option("--variant", type=click.Choice(["all", "synthetic", "real"]), default="all",
              show_default=True, help="Which data variant's tables to show.")
@click.option("--no-published", is_flag=True, help="Leave out the paper's published rows.")
@click.option("--out", type=click.Path(dir_okay=False), help="Write to a file instead of stdout.")
def leaderboard(results_dir: str, fmt: str, variant: str, no_published: bool, out: str | None) -> None:
    """Leaderboard of every result under --results: Table 1 layout plus per-sequence tables.

    Synthetic and real results are separate tables; published numbers are labelled rows
    beside real results only.
    """
    records = find_results(Path(results_dir))
    variants = ("synthetic", "real") if variant == "all" else (variant,)
    text = render_all(records, fmt, variants=variants, published=not no_published)
    if not records:
        click.echo(f"note: no results.json under {results_dir}; showing published rows only", err=True)
    if out:
        from benchmark.io import atomic_write_text

        atomic_write_text(out, text)
        click.echo(f"wrote {out}")
    else:
        click.echo(text, nl=False)
