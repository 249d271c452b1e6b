"""``trase-bench prepare DATASET RAW_DIR OUT_DIR``: raw multi-view downloads -> training frames."""

from __future__ import annotations

from pathlib import Path

import click


@click.command()
@click.argument("dataset")
@click.argument("raw_dir", type=click.Path(file_okay=False, path_type=Path))
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--sequence", help="Sequence name (default: RAW_DIR's folder name). With RAW_DIR "
              "holding several sequence folders, all known ones are prepared into OUT_DIR/<sequence>.")
@click.option("--points", type=click.Path(dir_okay=False, path_type=Path),
              help="Initial point cloud (.ply/.npy) in the raw cameras' world; default: frustum samples.")
@click.option("--frames", "frame_span", metavar="FIRST-LAST",
              help="Only these publisher frame numbers (inclusive), e.g. 0-9 for a quick look; "
              "default: the benchmark's range.")
def prepare(dataset: str, raw_dir: Path, out_dir: Path, sequence: str | None, points: Path | None,
            frame_span: str | None) -> None:
    """Extract, downscale and undistort frames of DATASET from RAW_DIR into OUT_DIR.

    Neu3D: frames 0-299 of camNN.mp4, 2x down. Immersive: first 50 frames of each fisheye
    video, 2x down, undistorted to pinhole, principal point centred. Technicolor: the paper's
    frame range, 2x down, principal point centred. Resumable; writes OUT_DIR/prepared.json.
    """
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    from benchmark.datasets.errors import fail
    from benchmark.datasets.prepare import prepare_sequence
    from benchmark.datasets.registry import get_dataset

    spec = get_dataset(dataset)
    frames = None
    if frame_span is not None:
        try:
            first, last = (int(x) for x in frame_span.split("-"))
        except ValueError:
            raise fail("--frames", f"expected FIRST-LAST, got {frame_span!r}") from None
        if first < 0 or last < first:
            raise fail("--frames", f"empty or negative range {frame_span!r}")
        frames = list(range(first, last + 1))
    if spec.format == "nerfies":
        raise fail(raw_dir, f"{spec.key} needs no preparation: load_scene reads its rgb/{spec.downscale}x images directly")
    jobs: list[tuple[Path, Path, str | None]]
    known = {n: s for s in spec.sequences for n in spec.folder_names(s)}
    if sequence is None and raw_dir.name not in known:
        subs = sorted(p for p in raw_dir.iterdir() if p.is_dir() and p.name in known) if raw_dir.is_dir() else []
        if not subs:
            raise fail(raw_dir, f"is no {spec.key} sequence folder and holds none ({', '.join(spec.sequences)})")
        jobs = [(p, out_dir / known[p.name], known[p.name]) for p in subs]
    else:
        jobs = [(raw_dir, out_dir, sequence)]
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn()) as bar:
        for src, dst, seq in jobs:
            task = bar.add_task(f"{spec.key}/{seq or src.name}", total=None)
            m = prepare_sequence(spec.key, src, dst, seq, points=points, frames=frames,
                                 on_start=lambda n, t=task: bar.update(t, total=n),
                                 on_image=lambda t=task: bar.advance(t))
            bar.console.print(f"{dst}: {m['n_images']} images, {len(m['cameras'])} cameras, "
                              f"points: {m['points_source']}")
