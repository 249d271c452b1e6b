"""``trase-bench fit``: the method on a capture of one's own (no ground truth)."""

from __future__ import annotations

from pathlib import Path

import click


@click.command()
@click.option("--scene", "scene_dir", required=True, type=click.Path(file_okay=False),
              help="The capture's folder (nerfies capture, COLMAP folder, transforms json, or a multi-view recording after trase-bench prepare).")
@click.option("--format", "fmt", default="auto", show_default=True,
              type=click.Choice(["auto", "nerfies", "colmap", "transforms", "prepared"]), help="Capture layout.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Output folder (default fits/<scene folder name>).")
@click.option("--holdout", default="none", show_default=True, metavar="none|every:N|layout",
              help="Views held out to report reconstruction PSNR; all views train by default.")
@click.option("--method", default="trase", show_default=True, help="Registered method.")
@click.option("--cache", "cache_dir", type=click.Path(file_okay=False), default=None,
              help="Stage cache (default <out>/.cache).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a setting, e.g. --set preset=paper, --set masks.generator=sam "
                   "--set masks.checkpoint=sam_vit_h.pth, --set capture.image_scale=4 (repeatable).")
@click.option("--quiet", is_flag=True, help="No progress output.")
def fit(scene_dir, fmt, out_dir, holdout, method, cache_dir, overrides, quiet) -> None:
    """Masks -> reconstruction -> features -> clusters on any capture, then export.

    Writes <out>/fit.json, the geometry (model/), the segmentation (segmentation/), the views'
    cameras and cluster previews. The same stage cache as `trase-bench run`: a rerun with
    other clustering settings reuses the masks, the reconstruction and the features. A fitted
    capture is never a benchmark result.
    """
    from benchmark.captures.fit import FitOptions, fit_capture, next_steps

    path = fit_capture(FitOptions(Path(scene_dir), Path(out_dir) if out_dir else None, method, fmt, holdout,
                                  list(overrides), Path(cache_dir) if cache_dir else None, not quiet))
    click.echo(f"fitted -> {path.parent}")
    for line in next_steps(path):
        click.echo(f"  {line}")
