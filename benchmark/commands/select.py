"""``trase-bench select``: objects of a fitted capture chosen by clicks or 2D masks."""

from __future__ import annotations

import click

from benchmark.commands.text_options import text_options, text_request


@click.command(name="select")
@click.option("--fit", "fit_dir", required=True, type=click.Path(file_okay=False),
              help="A folder written by trase-bench fit.")
@click.option("--click", "clicks", multiple=True, metavar="VIEW:X,Y",
              help="A view's name and a pixel (column X, row Y); repeat for more objects.")
@click.option("--unclick", "unclicks", multiple=True, metavar="VIEW:X,Y",
              help="A negative click, taken before the clicks: the cluster under it stays out of the selection, "
                   "so a --click where it blends with another object picks the other; repeatable.")
@click.option("--mask", "masks", multiple=True, metavar="VIEW:PATH",
              help="A view's name and an image of a 2D mask of it (alpha of an RGBA cut-out, else non-zero "
                   "pixels): the clusters it covers; repeatable.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Where the masks go (default <fit>/selection).")
@text_options
def select(fit_dir, clicks, unclicks, masks, out_dir, **text) -> None:
    """Masks of the objects chosen by clicks, 2D masks or text at every view of the capture (PNG, 0/255)."""
    from benchmark.captures.select import select_clicks

    res = select_clicks(fit_dir, list(clicks), out_dir, masks=list(masks), unclicks=list(unclicks),
                        text=text_request(**text))
    for choice in res["per_text"]:
        click.echo(f"text {choice.line()}")
    chosen = ", ".join(map(str, res["clusters"])) or "none (the prompts hit no surface)"
    per = [f"per click: {res['per_click']}"] * bool(clicks or unclicks) + [f"per mask: {res['per_mask']}"] * bool(masks)
    click.echo(f"clusters {chosen} ({'; '.join(per)}); {len(res['masks'])} masks -> {res['dir']}")
