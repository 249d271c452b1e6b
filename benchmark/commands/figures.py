"""``trase-bench figures``: the figures page (docs/figures.md), measured and written from its data."""

from __future__ import annotations

from pathlib import Path

import click

from benchmark.commands import old_spelling


@click.command()
@old_spelling("--out", "--runs")
@old_spelling("--format", "--dataset")
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default="runs/figures", show_default=True,
              help="The folder of the figures' runs (their stage cache inside): reruns reuse what is there.")
@click.option("--seeds", default="3", show_default=True, metavar="N|S,S,...", help="Run seeds per format and geometry.")
@click.option("--dataset", "formats", multiple=True,
              help="Only these formats, by their benchmark's key (repeatable; default all five: nerfds, "
                   "hypernerf, neu3d, immersive, technicolor).")
@click.option("--geometry", "geometries", multiple=True, type=click.Choice(["reconstruct", "ground-truth"]),
              help="Only this geometry source (repeatable; default both).")
@click.option("--collect-only", is_flag=True, help="Summarise the runs already under --runs; run nothing.")
@click.option("--from-data", is_flag=True,
              help="Only write --write-page from the --data file as it is: run and summarise nothing "
                   "(a page's block after a change of its rendering; README.md's results table).")
@click.option("--data", "data_path", type=click.Path(dir_okay=False), default="docs/figures.json", show_default=True,
              help="The summary written (and read by --write-page).")
@click.option("--write-page", "page", type=click.Path(dir_okay=False), default=None, is_flag=False,
              flag_value="docs/figures.md", help="Rewrite this page's figures block from --data (default docs/figures.md).")
@click.option("--method", "methods", multiple=True,
              help="Methods to measure (repeatable; default trase). Several methods make the methods table: "
                   "write it with --data docs/methods-figures.json --write-page docs/competitors.md.")
@click.option("--update", is_flag=True,
              help="Replace only the rows this call summarises in the existing --data file (a re-measurement of "
                   "some methods, formats or geometries) and keep the others; cells whose runs came from another "
                   "instruction set than most are marked on the page.")
@click.option("--quiet", is_flag=True, help="No progress output.")
def figures(runs_dir, seeds, formats, geometries, collect_only, from_data, data_path, page, methods, update,
            quiet) -> None:
    """Run trase (or each --method) on the five built-in formats (reconstructed and ground-truth
    geometry, each for --seeds run seeds), summarise mean ± std over seeds into --data with the
    commit and machine, print the table, and with --write-page put it into the page's block
    (trase's figures block, or the methods table where the page has one).

    The whole measurement takes hours on 2 CPU cores (15 reconstructions of several minutes
    each); every stage is cached under --runs and measured runs are kept, so an interrupted
    measurement resumes.
    """
    from benchmark.config import parse_seeds
    from benchmark.errors import UserError
    from benchmark.results.figures import (
        FORMATS,
        GEOMETRIES,
        collect,
        merge,
        read_figures,
        render_block,
        write_json,
    )

    if from_data:
        if not page:
            raise UserError("--from-data writes a page from --data: give --write-page PAGE")
        write_page(Path(page), read_figures(Path(data_path)))
        return
    formats = tuple(formats) or FORMATS
    geometries = tuple(geometries) or GEOMETRIES
    methods = tuple(methods) or ("trase",)
    if not collect_only:
        run_figure_runs(Path(runs_dir), parse_seeds(seeds), formats, geometries, progress=not quiet, methods=methods)
    data = collect(Path(runs_dir), formats, geometries, methods)
    if update:
        if not Path(data_path).is_file():
            raise UserError(f"--update: {data_path} does not exist (nothing to update; leave --update out)")
        data = merge(read_figures(Path(data_path)), data)
    write_json(Path(data_path), data)
    if {r.get("method", "trase") for r in data["rows"]} - {"trase"}:  # trase's block shows trase's rows alone
        from benchmark.results.figures_methods import render_methods_block

        click.echo(render_methods_block(data))
    else:
        click.echo(render_block(data))
    click.echo(f"wrote {data_path}")
    if page:
        write_page(Path(page), data)


def run_figure_runs(out_dir: Path, seeds: list[int], formats, geometries, progress: bool, methods) -> None:
    """Every (method, format, geometry) main-protocol run for every seed, into ``out_dir``
    (stages cached, so methods share a scene's masks and geometry; a run already there with
    this config is kept, so an interrupted measurement resumes where it stopped)."""
    from benchmark.runner import RunOptions, run

    for method in methods:
        for geo in geometries:
            for ds in formats:
                overrides = [] if geo == "reconstruct" else ["geometry.source=ground-truth"]
                run(RunOptions(method=method, dataset=ds, out_dir=out_dir, overrides=overrides, seeds=seeds,
                               progress=progress, keep_existing=True))


def write_page(path: Path, data: dict) -> None:
    """Rewrite the block ``path`` holds (benchmark.results.figures.page_markers) from ``data``."""
    from benchmark.results.figures import page_markers, write_blocks

    markers, render = page_markers(path.read_text())
    write_blocks(path, [(markers, render(data))])
    click.echo(f"wrote the figures block of {path}")
