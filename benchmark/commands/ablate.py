"""``trase-bench ablate STUDY --dataset D``: the paper's ablation tables, generated."""

from __future__ import annotations

from pathlib import Path

import click

from benchmark.ablate import (
    STUDIES,
    differences,
    published_table,
    render_table,
    run_study,
    summarise,
)
from benchmark.commands import old_spelling


@click.command()
@old_spelling("--out", "--runs")
@click.argument("study", type=click.Choice(sorted(STUDIES)))
@click.option("--dataset", required=True)
@click.option("--sequence", "sequences", multiple=True, help="Sequence(s); default as `run`.")
@click.option("--data-root", type=click.Path(file_okay=False), default=None)
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default="runs", show_default=True,
              help="The folder of runs; the variants go to <runs>/ablations/STUDY/.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help="Applied to every variant.")
@click.option("--format", "fmt", type=click.Choice(["markdown", "latex", "csv"]), default="markdown",
              show_default=True)
@click.option("--seeds", default=None, metavar="N|S,S,...",
              help="Run seeds per variant: a count (3: seeds 0, 1, 2) or a list; the table shows mean ± std.")
@click.option("--quiet", is_flag=True, help="No progress output.")
def ablate(study, dataset, sequences, data_root, runs_dir, overrides, fmt, seeds, quiet) -> None:
    """Run every variant of STUDY (reusing cached masks and geometry) and print its table.

    Studies: smoothing (K 0/16/32), feature-dim (16/32/64/128, each with and without filtering,
    with storage and clustering time), subsample (2/10/25% with time), filtering (on/off),
    mask-sampling (random/area/score/grid), mining (soft/hard/all with intra/inter distances),
    clustering (HDBSCAN/DBSCAN/KMeans). Each follows its paper table's protocol (filtering as
    there); the published table and the remaining differences are printed under the measured
    one. Variants are runs of the study under <runs>/ablations/STUDY/ and never enter a
    leaderboard unless asked for.
    """
    from benchmark.config import parse_seeds

    df = run_study(study, dataset, Path(runs_dir), Path(data_root) if data_root else None,
                   list(sequences) or None, list(overrides), progress=not quiet,
                   seeds=parse_seeds(seeds) if seeds else None)
    s = STUDIES[study]
    data = ", ".join(sorted(set(df["data"])))
    click.echo(render_table(summarise(df), fmt, f"{s.title}: {dataset} ({data} data, measured, official metric)"))
    pub = published_table(study, dataset)
    if pub is not None:
        click.echo(render_table(pub, fmt, f"{s.title}: {dataset} (published, real data; not comparable "
                                          "with synthetic rows)"))
    elif fmt != "csv":
        click.echo(f"(the paper publishes no {s.title.lower()} figures for {dataset})\n")
    diffs = differences(study, dataset, df)
    if fmt != "csv" and diffs:
        click.echo("Differences from the paper's protocol:")
        for d in diffs:
            click.echo(f"- {d}")
