"""``trase-bench score PRED_DIR GT_DIR``: score a directory of predicted masks."""

from __future__ import annotations

import json

import click

from benchmark.scoring import METRICS, score_directories


@click.command()
@click.argument("pred_dir", type=click.Path(file_okay=False))
@click.argument("gt_dir", type=click.Path(file_okay=False))
@click.option("--metric", type=click.Choice(METRICS), default="v1", show_default=True,
              help="v1: this project's metric (masks binarised by one rule, both-empty frames left "
                   "out of mIoU); official: the public evaluation script's rules exactly.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of a table.")
def score(pred_dir: str, gt_dir: str, metric: str, as_json: bool) -> None:
    """Score predicted masks in PRED_DIR against ground truth in GT_DIR.

    v1 matches frames by file stem (00000.png, 00000.npy ...); a ground-truth frame with no
    prediction is scored as an empty prediction, a prediction with no ground truth is an error.
    official matches them by file name, as the public script does; a frame with no prediction is
    skipped, a prediction with no ground truth ignored, and both are listed. The rules of both
    metrics: docs/results.md, "Scoring".
    """
    result = score_directories(pred_dir, gt_dir, metric=metric)
    if as_json:
        click.echo(json.dumps(result.to_dict(), indent=2))
        return
    d = result.to_dict()
    fmt = lambda x: "n/a" if x is None else f"{x:.4f}"
    official = metric == "official"
    click.echo(f"metric     {d['metric_version']}")
    click.echo(f"frames     {d['n_frames']}" + (" scored" if official else ""))
    click.echo(f"mIoU       {fmt(d['miou'])}")
    click.echo(f"mAcc       {fmt(d['macc'])}")
    if official and d["pixel_macc"] != d["macc"]:
        click.echo(f"pixel mAcc {fmt(d['pixel_macc'])} (ground truth read as non-zero = foreground)")
    click.echo(f"pooled IoU {fmt(d['pooled_iou'])}")
    if d["both_empty"]:
        click.echo(f"both empty ({len(d['both_empty'])}): {', '.join(d['both_empty'])}")
    if d["missing"]:
        how = "skipped" if official else "scored as empty"
        click.echo(f"missing predictions ({len(d['missing'])}, {how}): {', '.join(d['missing'])}")
    if d.get("extra"):
        click.echo(f"extra predictions ({len(d['extra'])}, ignored): {', '.join(d['extra'])}")
    for note in d.get("notes", []):
        click.echo(f"note: {note}")
    for name, r in d.get("per_object", {}).items():
        click.echo(f"  object {name}: mIoU {fmt(r['miou'])}  mAcc {fmt(r['macc'])}")
