"""``trase-bench methods [--all] [--json]``: every method, built-in or from an installed package,
with where it comes from and one line about it (benchmark.plugins; docs/methods.md)."""

from __future__ import annotations

import json

import click


@click.command()
@click.option("--all", "show_all", is_flag=True,
              help="Also the feature objectives and mask generators (imports torch for the objectives).")
@click.option("--json", "as_json", is_flag=True, help="One JSON object: kind -> name -> source, description.")
def methods(show_all: bool, as_json: bool) -> None:
    """List the methods (built-in and from installed packages); a plugin that cannot be used is
    a one-line warning."""
    from benchmark.plugins import KINDS, listing

    kinds = list(KINDS) if show_all else ["method"]
    found = {kind: listing(kind) for kind in kinds}
    warnings = [w for _, ws in found.values() for w in ws]
    if as_json:
        out = {_key(kind): {r.name: r.to_dict() for r in rows} for kind, (rows, _) in found.items()}
        click.echo(json.dumps({**out, "warnings": warnings}, indent=1))
        return
    for kind, (rows, _) in found.items():
        click.echo(f"{kind}s ({KINDS[kind][2]}):")
        name_w = max((len(r.name) for r in rows), default=0)
        source_w = max((len(r.source) for r in rows), default=0)
        for r in rows:
            what = r.description if r.error is None else "cannot be used (see the warning below)"
            click.echo(f"  {r.name:<{name_w}}  {r.source:<{source_w}}  {what}")
    click.echo("a method of one's own, from a package of one's own: docs/methods.md")
    for w in warnings:
        click.echo(f"warning: {w}", err=True)


def _key(kind: str) -> str:
    return kind.replace(" ", "_") + "s"
