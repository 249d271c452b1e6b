"""``trase-bench select``: objects of a fitted capture chosen by clicks."""

from __future__ import annotations

import click


@click.command(name="select")
@click.option("--fit", "fit_dir", required=True, type=click.Path(file_okay=False),
              help="A folder written by trase-bench fit.")
@click.option("--click", "clicks", multiple=True, required=True, metavar="VIEW:X,Y",
              help="A view's name and a pixel (column X, row Y); repeat for more objects.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Where the masks go (default <fit>/selection).")
def select(fit_dir, clicks, out_dir) -> None:
    """Masks of the clicked objects at every view of the capture (PNG, 0/255)."""
    from benchmark.captures.select import select_clicks

    res = select_clicks(fit_dir, list(clicks), out_dir)
    chosen = ", ".join(map(str, res["clusters"])) or "none (the clicks hit no surface)"
    click.echo(f"clusters {chosen} (per click: {res['per_click']}); {len(res['masks'])} masks -> {res['dir']}")
