"""``trase-bench masks``: per-image "anything" masks for the training views of one sequence."""

from __future__ import annotations

import time
from pathlib import Path

import click

from benchmark.commands import old_spelling
from masks.generators import GENERATORS


def _instance_maps(scene) -> dict[str, Path]:
    """view name -> instance-id PNG, from the synthetic scene's manifest."""
    from benchmark.errors import UserError

    truth = scene.truth
    if truth is None:
        raise UserError(f"{scene.root}: --generator synthetic needs a synthetic scene "
                        "(no synthetic/manifest.json); use classical or sam for real data")
    if not truth.instance_maps:
        raise UserError(f"{truth.manifest_path}: the synthetic manifest lists no instance maps")
    for name, path in truth.instance_maps.items():
        if not path.is_file():
            raise UserError(f"{truth.manifest_path}: instance map of view {name!r} not found at {path}")
    return dict(truth.instance_maps)


@click.command()
@old_spelling("--no-progress", "--quiet")
@click.option("--dataset", required=True, help="Registry key: nerfds, hypernerf, neu3d, immersive, technicolor.")
@click.option("--sequence", default=None, help="Sequence name (default: the synthetic scene).")
@click.option("--generator", "generator_name", type=click.Choice(GENERATORS.names()), default=None,
              help="Default: synthetic for synthetic scenes, classical for real ones.")
@click.option("--data-root", type=click.Path(file_okay=False), default=None,
              help="Root of the real datasets (default: $TRASE_DATA).")
@click.option("--out", type=click.Path(file_okay=False), default=None,
              help="Output folder (default: <scene>/masks/<generator>).")
@click.option("--checkpoint", type=click.Path(dir_okay=False), default=None,
              help="SAM checkpoint (.pth), for --generator sam.")
@click.option("--model-type", default="vit_h", show_default=True, help="SAM backbone.")
@click.option("--device", default="cpu", show_default=True, help="SAM device (cpu, cuda).")
@click.option("--seed", default=0, show_default=True, help="Seed of the synthetic generator's noise.")
@click.option("--quiet", is_flag=True, help="No progress output.")
def masks(dataset, sequence, generator_name, data_root, out, checkpoint, model_type, device, seed,
          quiet) -> None:
    """Generate masks for every training view; views already done are skipped."""
    import numpy as np

    import masks as masklib
    from benchmark.datasets import load_scene
    from benchmark.datasets.synthetic import find_or_generate
    from masks.generators import make_generator

    scene_dir, variant = find_or_generate(dataset, sequence, data_root)
    if variant == "synthetic":  # its truth sits in the scene; no lookup under a data root
        gt = Path(scene_dir) / "gt_masks"
        scene = load_scene(dataset, scene_dir, None, gt_dir=gt if gt.is_dir() else None)
    else:
        scene = load_scene(dataset, scene_dir, sequence, data_root=data_root)
    name = generator_name or ("synthetic" if variant == "synthetic" else "classical")
    if name == "sam":
        gen = make_generator("sam", checkpoint=checkpoint or "", model_type=model_type, device=device)
    elif name == "synthetic":
        gen = make_generator("synthetic", seed=seed)
    else:  # classical, or a generator from an installed package
        gen = make_generator(name)
    ids = _instance_maps(scene) if name == "synthetic" else None
    out_dir = Path(out) if out else Path(scene_dir) / "masks" / name

    before = sum(masklib.mask_path(out_dir, v.name).exists() for v in scene.train)
    t0 = time.perf_counter()
    paths = masklib.generate_scene_masks(scene.train, gen, out_dir, progress=not quiet,
                                         instance_maps=ids)
    wall = time.perf_counter() - t0
    headers = [masklib.read_header(p) for p in paths]
    n_masks = [h["n"] for h in headers]
    secs = [h["info"].get("seconds") for h in headers if h["info"].get("seconds") is not None]
    sizes = [p.stat().st_size for p in paths]
    click.echo(f"scene      {scene.dataset}/{scene.sequence} ({variant}), {len(paths)} training views")
    click.echo(f"generator  {name}; {len(paths) - before} generated, {before} already there ({wall:.1f} s)")
    click.echo(f"masks      {out_dir}")
    if paths:
        h0 = headers[0]
        click.echo(f"per image  {np.mean(n_masks):.1f} masks (min {min(n_masks)}, max {max(n_masks)}) "
                   f"at {h0['width']}x{h0['height']}; {np.mean(sizes) / 1024:.1f} KiB on disk"
                   + (f"; {np.mean(secs):.3f} s to generate" if secs else ""))
