"""``trase-bench evaluate``: predicted masks made outside the benchmark, scored into runs."""

from __future__ import annotations

from pathlib import Path

import click

from benchmark.external.layout import FLAT_PATTERN, LAYOUTS, TRASE_PATTERN


@click.command()
@click.option("--predictions", required=True, type=click.Path(file_okay=False), metavar="DIR",
              help=f"One folder per sequence, named after it: {TRASE_PATTERN} (the public code's "
                   f"output/<DATASET>) or {FLAT_PATTERN}.")
@click.option("--dataset", required=True, help="nerfds, hypernerf, neu3d, immersive or technicolor.")
@click.option("--name", required=True,
              help="The method's name in runs and tables (not one of this benchmark's methods).")
@click.option("--layout", type=click.Choice(LAYOUTS), default="auto", show_default=True,
              help="trase: the public code's test/ours_<iteration>/pred_masks/; flat: mask files in the "
                   "sequence's folder; auto: decided per sequence folder.")
@click.option("--sequence", "sequences", multiple=True,
              help="Evaluate only these sequences (repeatable). Default: every sequence folder.")
@click.option("--data-root", type=click.Path(file_okay=False), default=None,
              help="Root of real data (default $TRASE_DATA); synthetic sequence names use the built-in scenes.")
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default="runs", show_default=True,
              help="The folder of runs: each run goes to <runs>/<name>/<dataset>/<sequence>/e<hash>.")
def evaluate(predictions, dataset, name, layout, sequences, data_root, runs_dir) -> None:
    """Score a method's predicted masks for the sequences of a benchmark and write one run of
    kind external per sequence, which `runs`, `leaderboard` and `report` show like any run.

    Ground truth is found as `trase-bench run` finds it; both metrics score the masks exactly as
    `trase-bench score MASKS GT_DIR` does. A test frame without a prediction is scored as empty
    by v1 and skipped by the official metric, and listed; a prediction for a frame the sequence
    does not have is an error. Nothing is written unless every sequence scores. Layouts and
    rules: docs/results.md, "External predictions".
    """
    from benchmark.external.evaluate import EvaluateOptions, evaluate_predictions
    from benchmark.results import load_results

    opts = EvaluateOptions(Path(predictions), dataset, name, layout, Path(runs_dir),
                           Path(data_root) if data_root else None, list(sequences) or None)
    outcome = evaluate_predictions(opts)
    fmt = lambda x: "n/a" if x is None else f"{x:.4f}"
    for path in outcome.results:
        r = load_results(path)
        m, official, ext = r["metrics"], r["metrics"]["official"], r["external"]
        v1 = "" if (m["miou"], m["macc"]) == (official["miou"], official["macc"]) else \
            f" (v1: {fmt(m['miou'])} / {fmt(m['macc'])})"
        where = ext["layout"] + (f" {ext['iteration_dir']}" if ext["iteration_dir"] else "")
        missing = f"; missing {len(ext['missing'])}: {', '.join(ext['missing'])}" if ext["missing"] else ""
        click.echo(f"{r['method']} {r['dataset']}/{r['sequence']} ({r['variant']}, external run {r['run']['name']}, "
                   f"{where}): mIoU {fmt(official['miou'])} mAcc {fmt(official['macc'])}{v1}  "
                   f"[{len(ext['files'])} masks for {m['n_frames']} test frames{missing}]  -> {path}")
    if outcome.not_evaluated:
        click.echo(f"note: no predictions for {len(outcome.not_evaluated)} {dataset} sequence(s) with data under "
                   f"the data root, not evaluated: {', '.join(outcome.not_evaluated)} (no {dataset} average for "
                   f"{name} in the leaderboard)", err=True)
