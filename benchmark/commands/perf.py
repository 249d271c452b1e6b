"""``trase-bench perf SUITE... [--quick] [--json OUT] [--write-page PAGE]``: measured performance suites."""

from __future__ import annotations

import inspect
import json
import time
from pathlib import Path

import click

from benchmark.perf import SUITES, get_suite, machine_info


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("suites", nargs=-1, type=click.Choice(SUITES.names()))
@click.option("--quick", is_flag=True, help="Small settings only (seconds, for smoke tests).")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Also write all figures to this JSON file.")
@click.option("--out-dir", type=click.Path(file_okay=False), default=None,
              help="Where suites write files (pareto.png). Default: the --json file's folder, else ./perf-out.")
@click.option("--dataset", default=None,
              help="The built-in scene's format for suites that take one (reconstruct, captures; "
                   "default: each suite's own, hypernerf); `none` with --scene: only the scenes (skip).")
@click.option("--scene", "scenes", multiple=True, type=click.Path(file_okay=False, exists=True),
              help="Scene folders for suites that take them (dnerf, skip: D-NeRF scenes as published; repeatable).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Settings for the fits of suites that take them (dnerf), e.g. --set preset=paper.")
@click.option("--lpips-weights", type=click.Path(file_okay=False, exists=True), default=None,
              help="A folder with torchvision's vgg16-397923af.pth and the lpips package's vgg.pth: LPIPS (VGG) "
                   "for the suites that measure images (dnerf).")
@click.option("--method", "methods", multiple=True,
              help="Methods for suites that compare them (methods; default: every registered method).")
@click.option("--variant", "variant_names", multiple=True, metavar="NAME",
              help="Only these variants, for suites that measure several (skip: full, static, converged, "
                   "resolution, resolution+primitives, primitives; keep full for the ratios to it; repeatable).")
@click.option("--threads", type=click.IntRange(min=1), default=None,
              help="Threads for torch and numba (default: theirs, all cores). On a shared, loaded "
                   "machine --threads 1 gives the steadiest side-by-side ratios.")
@click.option("--write-page", "page", type=click.Path(dir_okay=False, exists=True), default=None,
              help="Write the figures of --json into the page's generated block: raster, features, knn and "
                   "cluster into docs/performance.md's, skip into docs/skip.md's.")
@click.option("--from-json", "from_json", is_flag=True,
              help="With --write-page: run nothing, write the page from the --json file as it is.")
def perf(suites: tuple[str, ...], quick: bool, json_out: str | None, out_dir: str | None,
         dataset: str | None, scenes: tuple[str, ...], overrides: tuple[str, ...], lpips_weights: str | None,
         methods: tuple[str, ...], variant_names: tuple[str, ...], threads: int | None, page: str | None,
         from_json: bool) -> None:
    """Run performance SUITES (default: all that this machine can run) and print their figures."""
    if page and not json_out:
        raise click.UsageError("--write-page renders a --json file: give --json FILE")
    if from_json:
        if not page:
            raise click.UsageError("--from-json writes a page from --json: give --write-page PAGE")
        _write_page(page, json_out)
        return
    _run_suites(suites, quick, json_out, out_dir, dataset, scenes, overrides, lpips_weights, methods, threads,
                variant_names)
    if page:
        _write_page(page, json_out)


def _write_page(page: str, json_out: str) -> None:
    from benchmark.perf.skip_page import SKIP_BEGIN, SKIP_END, render_skip_block
    from benchmark.results.perf_page import PERF_BEGIN, PERF_END, render_perf_block, write_perf_page

    write_perf_page(Path(page), Path(json_out), {(PERF_BEGIN, PERF_END): render_perf_block,
                                                 (SKIP_BEGIN, SKIP_END): render_skip_block})
    click.echo(f"wrote the figures of {json_out} into {page}")


def _run_suites(suites, quick, json_out, out_dir, dataset, scenes, overrides, lpips_weights, methods,
                threads, variant_names=()) -> None:
    """Each suite named (default: all this machine can run), its figures printed and, with
    ``json_out``, written."""
    names = suites or tuple(SUITES.names())
    no_dataset = dataset == "none"
    if no_dataset:
        takes = [n for n in names if "datasets" in inspect.signature(get_suite(n)).parameters]
        if not scenes or takes != list(names):
            raise click.UsageError("--dataset none measures only the --scene folders: give --scene, and only "
                                   "suites that measure scenes beside the formats (skip)")
        dataset = None
    if dataset is not None:
        from benchmark.datasets import get_dataset

        dataset = get_dataset(dataset).key  # one-line error for an unknown name
        takes = [n for n in names if "dataset" in inspect.signature(get_suite(n)).parameters]
        if not takes:
            raise click.UsageError(f"--dataset: none of {', '.join(names)} takes a dataset "
                                   "(suites that do: reconstruct, captures, methods, skip)")
    if variant_names and not [n for n in names if "variant_names" in inspect.signature(get_suite(n)).parameters]:
        raise click.UsageError(f"--variant: none of {', '.join(names)} measures variants (the suite that does: skip)")
    if threads:
        import numba
        import torch

        torch.set_num_threads(threads)
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    result = {"machine": machine_info(), "started": time.strftime("%Y-%m-%dT%H:%M:%S"), "suites": {},
              "threads": threads, "dataset": dataset}
    for name in names:
        click.echo(f"== {name} ==")
        fn = get_suite(name)
        why = getattr(inspect.getmodule(fn), "unavailable", lambda: None)()  # e.g. no GPU here
        if why and scenes and "scenes" in inspect.signature(fn).parameters:
            why = None  # the scenes it lacked are given
        if why and not suites:  # "all": what this machine can run; a suite named is run (and fails)
            click.echo(f"skipped: {why}")
            result["suites"][name] = {"skipped": why}
            continue
        extra = {}
        if "out_dir" in inspect.signature(fn).parameters:  # suites that write files (pareto)
            extra["out_dir"] = Path(out_dir) if out_dir else (Path(json_out).parent if json_out else Path("perf-out"))
        if dataset is not None and "dataset" in inspect.signature(fn).parameters:
            extra["dataset"] = dataset
        if no_dataset:
            extra["datasets"] = []
        if scenes and "scenes" in inspect.signature(fn).parameters:
            extra["scenes"] = list(scenes)
        if overrides and "overrides" in inspect.signature(fn).parameters:
            extra["overrides"] = list(overrides)
        if methods and "methods" in inspect.signature(fn).parameters:
            extra["methods"] = list(methods)
        if variant_names and "variant_names" in inspect.signature(fn).parameters:
            extra["variant_names"] = list(variant_names)
        if lpips_weights and "lpips_weights" in inspect.signature(fn).parameters:
            extra["lpips_weights"] = lpips_weights
        result["suites"][name] = fn(quick=quick, echo=click.echo, **extra)
    if json_out:
        with open(json_out, "w") as f:
            json.dump(result, f, indent=2)
        click.echo(f"wrote {json_out}")


perf.help = (perf.help or "") + "\n\n\b\nSuites:\n" + "\n".join(f"  {e.name}: {e.help}" for e in SUITES)
