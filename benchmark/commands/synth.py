"""``trase-bench synth --dataset D --out DIR``: write one synthetic scene in a benchmark's raw format."""

from __future__ import annotations

import time

import click

DATASET_CHOICES = ("nerfds", "hypernerf", "neu3d", "immersive", "technicolor")


@click.command()
@click.option("--dataset", required=True, type=click.Choice(DATASET_CHOICES), help="Which format / rig.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Scene directory to create (must be empty or absent).")
@click.option("--seed", default=0, show_default=True, type=int, help="Colours, textures, motion phases.")
@click.option("--size", default="small", show_default=True, type=click.Choice(("tiny", "small", "medium")),
              help="small: <= 160 px wide at training resolution; medium: for benchmarks; tiny: tests.")
@click.option("--difficulty", default="standard", show_default=True, type=click.Choice(("standard", "hard")),
              help="standard: the benchmark's frames per sequence and motion per frame; hard: the whole "
                   "motion in 10-60 frames (the earlier scenes, for stress runs).")
def synth(dataset: str, out_dir: str, seed: int, size: str, difficulty: str) -> None:
    """Generate a procedural dynamic scene with exact ground truth in DATASET's raw format.

    Writes the publisher's files (and, for multi-view formats, the prepared frames), then
    gt_masks/ for the test views and synthetic/ (manifest, per-view instance ids, geometry.npz).
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from benchmark.background_compile import kernels_compiled_meanwhile
    from benchmark.datasets.synthetic import generate

    t0 = time.perf_counter()
    with Progress(TextColumn("{task.description:<9}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), transient=False) as bar:
        tasks: dict[str, int] = {}

        def report(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=max(total, 1))
            bar.update(tasks[stage], completed=done, total=max(total, 1))

        with kernels_compiled_meanwhile():  # a run on this scene needs them next
            path = generate(dataset, out_dir, seed=seed, size=size, progress=report, difficulty=difficulty)
    click.echo(f"wrote {dataset} synthetic scene (size {size}, {difficulty}, seed {seed}) to {path} "
               f"in {time.perf_counter() - t0:.1f} s")
