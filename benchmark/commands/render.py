"""``trase-bench render``: frames and a clip of a run, a fitted capture or an edited scene."""

from __future__ import annotations

import click


@click.command(name="render")
@click.option("--run", "run_dir", required=True, type=click.Path(exists=True, file_okay=False),
              help="A run, a trase-bench fit folder or an edited scene.")
@click.option("--cache", type=click.Path(file_okay=False), default=None,
              help="Stage cache of a run (default: the .cache above it).")
@click.option("--mode", type=click.Choice(["rgb", "depth", "clusters", "selection", "pca"]), default="rgb",
              show_default=True, help="What to draw.")
@click.option("--cameras", type=click.Choice(["test", "orbit"]), default="test", show_default=True,
              help="test: the folder's views in time order; orbit: an arc around the scene over time.")
@click.option("--frames", default=0, type=int, help="How many frames (0: every view; 60 for an orbit).")
@click.option("--orbit-degrees", default=30.0, type=float, show_default=True, help="Width of the orbit's arc.")
@click.option("--scale", default=1.0, type=float, show_default=True, help="Image size factor.")
@click.option("--fps", default=10.0, type=float, show_default=True)
@click.option("--mp4/--no-mp4", default=True, show_default=True, help="Also write <mode>.mp4.")
@click.option("--clusters", default=None, metavar="IDS", help="Selection mode: cluster ids, e.g. 3,7.")
@click.option("--click", "clicks", multiple=True, metavar="VIEW:X,Y", help="Selection mode: the cluster under a click.")
@click.option("--selected", is_flag=True, help="Selection mode: the clusters the run's prompts chose.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Where frames go (default <run>/renders).")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def render(run_dir, cache, mode, cameras, frames, orbit_degrees, scale, fps, mp4, clusters, clicks, selected,
           out_dir, quiet) -> None:
    """Render frames (PNG), an MP4 and an animated WebP preview of a scene folder."""
    from pathlib import Path

    from benchmark.errors import UserError
    from benchmark.scene.folders import open_scene_folder, resolve_selection
    from benchmark.scene.render import RenderOptions, render_frames

    folder = open_scene_folder(run_dir, cache)
    ks, sel = resolve_selection(folder, clusters, clicks, selected)
    if mode == "selection" and sel is None:
        if not folder.selected:
            raise UserError("selection mode: say what to select (--clusters, --click or --selected)")
        ks, sel = resolve_selection(folder, selected=True)
    opts = RenderOptions(mode=mode, cameras=cameras, frames=frames, orbit_degrees=orbit_degrees, fps=fps,
                         scale=scale, mp4=mp4)
    out = Path(out_dir) if out_dir else Path(run_dir) / "renders"
    res = render_frames(folder, opts, out, sel, progress=not quiet)
    w, h = res["size"]
    click.echo(f"{res['n']} frames {w}x{h} ({mode}{', clusters ' + str(ks) if sel is not None else ''}) -> "
               f"{res['frames']}/  {res['seconds_per_frame'] * 1000:.0f} ms/frame (median)")
    for k in ("mp4", "preview"):
        if k in res:
            click.echo(f"{k}: {res[k]}")
