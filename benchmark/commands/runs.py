"""``trase-bench runs``: every run under a folder of runs, with its kind and protocol."""

from __future__ import annotations

import json
from pathlib import Path

import click

from benchmark.commands import old_spelling

KIND_CHOICES = ["all", "main", "run", "ablation", "external"]


@click.command()
@old_spelling("--results", "--runs")
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default="runs", show_default=True,
              help="The folder of runs (searched recursively).")
@click.option("--kind", type=click.Choice(KIND_CHOICES), default="all", show_default=True,
              help="main: made with the method's defaults; run: with --set overrides; ablation: study variants; "
                   "external: predictions scored by `trase-bench evaluate`.")
@click.option("--json", "as_json", is_flag=True, help="One JSON object per run instead of a table.")
def runs(runs_dir: str, kind: str, as_json: bool) -> None:
    """List runs: method, dataset, sequence, name, kind, run seed, mIoU (official metric),
    config hash, directory, and a legend of the protocols (geometry, features preset, masks, prompts,
    render rule, metric) they were measured under."""
    from benchmark.results.runs import ProtocolLegend, find_runs, protocol, protocol_label

    records = find_runs(Path(runs_dir), warn=lambda m: click.echo(m, err=True))
    if kind != "all":
        records = [r for r in records if r["run"]["kind"] == kind]
    if not records:
        click.echo(f"no runs under {runs_dir}" + ("" if kind == "all" else f" of kind {kind}"), err=True)
        return
    legend = ProtocolLegend()
    rows = []
    for r in records:
        label = protocol_label(protocol(r))
        study = r["run"].get("study") or {}
        off = r["metrics"]["official"]
        rows.append({
            "method": r["method"], "dataset": r["dataset"], "sequence": r["sequence"], "name": r["run"]["name"],
            "kind": r["run"]["kind"] + (f" {study['name']}/{study['variant']}" if study else ""),
            "seed": r["run"]["seed"],
            "data": r["variant"], "mIoU": off["miou"], "mAcc": off["macc"], "protocol": legend.key(label),
            "config": r["config_hash"][:8], "created": str(r.get("created", ""))[:16], "dir": r["_dir"],
            "overrides": r["run"]["overrides"],
        })
    if as_json:
        labels = {k: lab for lab, k in legend.keys.items()}
        for row in rows:
            click.echo(json.dumps(row | {"protocol": labels[row["protocol"]]}))
        return
    import pandas as pd

    df = pd.DataFrame(rows).drop(columns=["overrides"])
    click.echo(df.to_string(index=False, float_format=lambda x: f"{x:.4f}"))
    click.echo("\nprotocols:")
    for note in legend.notes():
        click.echo(f"  {note}")
