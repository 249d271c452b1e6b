"""``trase-bench view``: a web viewer of a run, a fitted capture or an edited scene."""

from __future__ import annotations

import click

from benchmark.commands.text_options import text_model_options, text_request


@click.command(name="view")
@click.option("--run", "run_dir", required=True, type=click.Path(exists=True, file_okay=False),
              help="A run, a trase-bench fit folder or an edited scene.")
@click.option("--cache", type=click.Path(file_okay=False), default=None,
              help="Stage cache of a run (default: the .cache above it).")
@click.option("--host", default="127.0.0.1", show_default=True, help="0.0.0.0 to serve other machines.")
@click.option("--port", default=8080, type=int, show_default=True)
@click.option("--height", type=click.Choice(["120", "240", "480"]), default="240", show_default=True,
              help="Render height in pixels (the width follows the browser window).")
@click.option("--device", type=click.Choice(["auto", "cpu", "cuda"]), default="auto", show_default=True,
              help="Where frames are drawn: cuda uses the rasterizer's gsplat backend (needs gsplat and a GPU).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Where Export writes the edited scene (default <run>-edited).")
@text_model_options
def view(run_dir, cache, host, port, height, device, out_dir, **text) -> None:
    """Open a scene in the browser: orbit, time, render modes, click and text selection, edits, export."""
    import time

    from benchmark.scene.folders import open_scene_folder
    from benchmark.scene.viewer import SceneViewer

    folder = open_scene_folder(run_dir, cache)
    viewer = SceneViewer(folder, host=host, port=port, out=out_dir, height=int(height), device=device,
                         text=text_request(**text))
    click.echo(f"viewer of {folder.path} at {viewer.url()}  (drawn on {viewer.painter.device}; Ctrl+C to stop)")
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
