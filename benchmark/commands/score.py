"""``trase-bench score PRED_DIR GT_DIR``: score a directory of predicted masks."""

from __future__ import annotations

import json

import click

from benchmark.scoring import METRICS, score_directories


@click.command()
@click.argument("pred_dir", type=click.Path(file_okay=False))
@click.argument("gt_dir", type=click.Path(file_okay=False))
@click.option("--metric", type=click.Choice(METRICS), default="v1", show_default=True,
              help="v1: both-empty frames excluded from mIoU; official: the public script.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of a table.")
def score(pred_dir: str, gt_dir: str, metric: str, as_json: bool) -> None:
    """Score predicted masks in PRED_DIR against ground truth in GT_DIR.

    Frames are matched by file name (00000.png ...). A ground-truth frame with no prediction
    is scored as an empty prediction and listed as missing.
    """
    result = score_directories(pred_dir, gt_dir, metric=metric)
    if as_json:
        click.echo(json.dumps(result.to_dict(), indent=2))
        return
    d = result.to_dict()
    fmt = lambda x: "n/a" if x is None else f"{x:.4f}"  # noqa: E731
    click.echo(f"metric     {d['metric_version']}")
    click.echo(f"frames     {d['n_frames']}")
    click.echo(f"mIoU       {fmt(d['miou'])}")
    click.echo(f"mAcc       {fmt(d['macc'])}")
    click.echo(f"pooled IoU {fmt(d['pooled_iou'])}")
    if d["both_empty"]:
        click.echo(f"both empty ({len(d['both_empty'])}): {', '.join(d['both_empty'])}")
    if d["missing"]:
        click.echo(f"missing predictions ({len(d['missing'])}): {', '.join(d['missing'])}")
    for name, r in d.get("per_object", {}).items():
        click.echo(f"  object {name}: mIoU {fmt(r['miou'])}  mAcc {fmt(r['macc'])}")
