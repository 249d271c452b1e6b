"""``trase-bench run``: the whole pipeline for one method on one benchmark."""

from __future__ import annotations

from pathlib import Path

import click

from benchmark.commands import old_spelling


def stopped_stages(record: dict) -> str:
    """`` [stop when converged: features stopped at 1000 of 3000, ...]`` for the stages that
    stop when converged."""
    said = []
    for stage in ("geometry", "features"):
        st = ((record.get("stages") or {}).get(stage) or {}).get("info") or {}
        st = st.get("stopping")
        if st:
            at = st.get("stopped_at")
            said.append(f"{stage} stopped at {at} of {st['cap']}" if at is not None else
                        f"{stage} ran all {st['cap']}")
    return f" [stop when converged: {', '.join(said)}]" if said else ""


@click.command()
@old_spelling("--out", "--runs")
@click.option("--method", required=True, help="A method: trase, trase-hard, trase-all, cgc, opengaussian, one from an "
                                               "installed package (trase-bench methods lists them), or a command "
                                               "method's TOML file (docs/command-methods.md).")
@click.option("--dataset", required=True, help="nerfds, hypernerf, neu3d, immersive or technicolor.")
@click.option("--sequence", "sequences", multiple=True,
              help="Sequence(s) to run (repeatable). Default: every sequence found under the data "
                   "root, else the built-in synthetic scene.")
@click.option("--data-root", type=click.Path(file_okay=False), default=None,
              help="Root of real data (default $TRASE_DATA).")
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default="runs", show_default=True,
              help="The folder of runs: each run goes to <runs>/<method>/<dataset>/<sequence>/<name>.")
@click.option("--cache", "cache_dir", type=click.Path(file_okay=False), default=None,
              help="Stage cache (default <runs>/.cache).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a setting, e.g. --set geometry.source=ground-truth "
                   "--set method.features.iterations=500 (repeatable).")
@click.option("--name", default=None,
              help="Name of the run's directory (default: c + 8 hex digits of the resolved config's hash). "
                   "A run with another config under this name is never overwritten.")
@click.option("--seeds", default=None, metavar="N|S,S,...",
              help="Run seeds: a count (3: seeds 0, 1, 2) or a list (0,4,7). Each seed is its own run "
                   "(<name>-s<seed>; seed 0 keeps the plain name); tables show mean ± std over seeds. "
                   "One seed: --set seed=S.")
@click.option("--jobs", type=int, default=1, show_default=True, help="Sequences run in parallel.")
@click.option("--quiet", is_flag=True, help="No progress output.")
def run(method, dataset, sequences, data_root, runs_dir, cache_dir, overrides, name, seeds, jobs, quiet) -> None:
    """Run masks -> geometry -> features/clustering -> prompts -> evaluation per sequence.

    Each stage is cached under a key of its inputs and config: reruns and other methods on
    the same scene reuse what they can. Writes <runs>/<method>/<dataset>/<sequence>/<name>/results.json:
    one directory per config, so a rerun with other --set values never replaces a result. A run
    without --set is the method's main run (what `trase-bench leaderboard` shows by default).
    """
    from benchmark.config import parse_seeds
    from benchmark.runner import RunOptions
    from benchmark.runner import run as run_pipeline

    opts = RunOptions(method=method, dataset=dataset, sequences=list(sequences) or None,
                      data_root=Path(data_root) if data_root else None, out_dir=Path(runs_dir),
                      cache_dir=Path(cache_dir) if cache_dir else None, overrides=list(overrides),
                      jobs=jobs, progress=not quiet, name=name, seeds=parse_seeds(seeds) if seeds else None)
    from benchmark.results import load_results

    paths = run_pipeline(opts)
    for path in paths:
        r = load_results(path)
        m, official = r["metrics"], r["metrics"]["official"]
        fmt = lambda x: "n/a" if x is None else f"{x:.4f}"
        oracle = r.get("oracle") or {}
        ceiling = f", geometry ceiling {fmt(r['ceiling'].get('miou'))}" if r.get("ceiling") else ""
        v1 = "" if (m["miou"], m["macc"]) == (official["miou"], official["macc"]) else \
            f" (v1: {fmt(m['miou'])} / {fmt(m['macc'])})"
        corr = r.get("corrective")
        if corr:  # the single-click score, then the clicks the robot user made
            curve = corr["curve"]
            v1 += (f"; after {curve[-1]['clicks']} clicks of at most {corr['first_clicks'] + corr['budget']} "
                   f"(mIoU@1 {fmt(curve[0]['miou'])}, NoC@85 {corr['noc@85']}, NoC@90 {corr['noc@90']})")
        text = r.get("text")
        if text:  # the text protocol: each phrase's view and clusters
            v1 += "; " + ", ".join(f"{p['phrase']!r} -> {p['clusters'] or 'nothing'}" for p in text["phrases"])
        sets = r.get("click_sets")
        if sets:
            ceiling += f", click sets median {fmt(sets['median'])} worst {fmt(sets['worst'])} of {sets['n']}"
        click.echo(f"{r['method']} {r['dataset']}/{r['sequence']} ({r['variant']}, run "
                   f"{r['run']['name']}, {r['run']['kind']}, seed {r['run']['seed']}): mIoU {fmt(official['miou'])} mAcc {fmt(official['macc'])}{v1}  "
                   f"[oracle mIoU {fmt(oracle.get('miou'))}{ceiling}]{stopped_stages(r)}  -> {path}")
    if opts.seeds and len(opts.seeds) > 1:
        from benchmark.results.runs import load_run
        from benchmark.results.stability import format_summary, seed_summary

        by_seq: dict[str, list[dict]] = {}
        for path in paths:
            rec = load_run(path)
            by_seq.setdefault(rec["sequence"], []).append(rec)
        for seq, recs in by_seq.items():
            click.echo(f"{method} {dataset}/{seq} over {format_summary(seed_summary(recs))}")
