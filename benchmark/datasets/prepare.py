"""``prepare``: raw multi-view downloads -> the frames and cameras that training reads.

Output (``OUT_DIR``)::

    images/<camera>/<frame:05d>.png   training resolution, undistorted, principal point centred
    cameras.json                      per camera: training pinhole camera + native lens model
    points.npy [, point_colors.npy]   initial point cloud (given with --points, else frustum samples)
    prepared.json                     the manifest, written last: what was produced from what
                                      (paths relative to OUT_DIR, no timestamp)

Resumable: images are written atomically and skipped when present, so an interrupted run
continues where it stopped; the manifest only exists once everything is there. Nerfies
datasets need no preparation (their rgb/2x images are read directly).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmark.datasets.errors import DatasetError, fail
from benchmark.datasets.images import write_image
from benchmark.datasets.points import frustum_points, read_points
from benchmark.datasets.rectify import make_rectifier
from benchmark.datasets.registry import DatasetSpec, get_dataset
from benchmark.io import read_json

MANIFEST = "prepared.json"
FORMAT_VERSION = 1


def open_source(spec: DatasetSpec, raw_dir: Path):
    """The raw reader of a multi-view format: ``.cameras`` (native) and ``.frames(cam, frames)``."""
    if spec.format == "neu3d":
        from benchmark.datasets.neu3d import Neu3DSource

        return Neu3DSource(raw_dir)
    if spec.format == "immersive":
        from benchmark.datasets.immersive import ImmersiveSource

        return ImmersiveSource(raw_dir)
    if spec.format == "technicolor":
        from benchmark.datasets.technicolor import TechnicolorSource

        return TechnicolorSource(raw_dir)
    raise fail(raw_dir, f"{spec.key} ({spec.format} format) needs no preparation; point the loader at it directly")


def image_path(out_dir: Path, camera: str, frame: int) -> Path:
    return out_dir / "images" / camera / f"{frame:05d}.png"


def prepare_sequence(
    dataset: str,
    raw_dir: Path | str,
    out_dir: Path | str,
    sequence: str | None = None,
    *,
    points: Path | str | None = None,
    frames: list[int] | None = None,
    on_start: Callable[[int], None] | None = None,
    on_image: Callable[[], None] | None = None,
) -> dict:
    """Prepare one sequence; returns the manifest. ``frames`` overrides the registry's range
    (tests, quick looks); ``on_start(total)`` / ``on_image()`` drive a progress bar."""
    spec = get_dataset(dataset)
    raw_dir, out_dir = Path(raw_dir), Path(out_dir)
    if not raw_dir.is_dir():
        raise fail(raw_dir, "raw directory does not exist")
    seq = _sequence(spec, raw_dir, sequence, frames)
    frame_list = list(frames) if frames is not None else spec.frames(seq)
    source = open_source(spec, raw_dir)
    names = [c.name for c in source.cameras]
    if spec.test_camera not in names:
        raise fail(raw_dir, f"test camera {spec.test_camera} is missing (cameras: {', '.join(names[:4])} ...)")
    _drop_manifest(out_dir, spec, seq)

    rect = {c.name: make_rectifier(spec, c) for c in source.cameras}
    out_dir.mkdir(parents=True, exist_ok=True)
    _write_json(out_dir / "cameras.json", [
        {"name": n, "camera": rect[n].camera.to_dict(), "native": rect[n].native.to_dict()} for n in names
    ])
    _write_images(source, rect, names, frame_list, out_dir, on_start, on_image)
    n_points, points_source = _write_points(source, rect, names, spec.test_camera, points, out_dir)

    cam0 = rect[names[0]].camera
    manifest = {
        "format_version": FORMAT_VERSION,
        "dataset": spec.key,
        "sequence": seq,
        "source_dir": _relative(raw_dir, out_dir),
        "frames": frame_list,
        "cameras": names,
        "test_camera": spec.test_camera,
        "resolution": [cam0.width, cam0.height],
        "image_pattern": "images/{camera}/{frame:05d}.png",
        "n_images": len(names) * len(frame_list),
        "points_source": points_source,
        "repaired_images": list(getattr(source, "repaired", [])),
        "n_points": n_points,
    }
    _write_json(out_dir / MANIFEST, manifest)
    return manifest


def _sequence(spec: DatasetSpec, raw_dir: Path, sequence: str | None, frames: list[int] | None) -> str:
    """The benchmark sequence ``sequence`` (default: the raw folder's name) names; any name
    when ``frames`` are given (not a benchmark sequence, e.g. a synthetic multi-view scene)."""
    name = sequence if sequence is not None else raw_dir.name
    try:
        return spec.resolve_sequence(name)
    except DatasetError:
        if frames is None:
            raise
        return name  # not a benchmark sequence (e.g. a synthetic scene): frames given explicitly


def _drop_manifest(out_dir: Path, spec: DatasetSpec, seq: str) -> None:
    """Remove an earlier run's manifest (rewritten once everything is there again), refusing a
    folder that holds another dataset's or sequence's frames."""
    old = out_dir / MANIFEST
    if old.is_file():
        prev = read_json(old, "prepared manifest")
        if not isinstance(prev, dict):
            raise fail(old, "prepared manifest is not a JSON object")
        if (prev.get("dataset"), prev.get("sequence")) != (spec.key, seq):
            raise fail(old, f"already holds {prev.get('dataset')}/{prev.get('sequence')}, not {spec.key}/{seq}")
        old.unlink()  # re-validated and rewritten below


def _write_images(source, rect: dict, names: list[str], frame_list: list[int], out_dir: Path,
                  on_start: Callable[[int], None] | None, on_image: Callable[[], None] | None) -> None:
    """The rectified frames of every camera that are not written yet (the resume point)."""
    todo = {n: [f for f in frame_list if not image_path(out_dir, n, f).is_file()] for n in names}
    total = sum(len(v) for v in todo.values())
    if on_start:
        on_start(total)
    for n in names:
        for fr, img in source.frames(n, todo[n]):
            write_image(image_path(out_dir, n, fr), rect[n](img))
            if on_image:
                on_image()


def _write_points(source, rect: dict, names: list[str], test_camera: str, points: Path | str | None,
                  out_dir: Path) -> tuple[int, str]:
    """points.npy [P, 3] (and point_colors.npy when the given cloud has colours; a stale one is
    removed): the cloud given with ``points``, else random samples in the training cameras'
    frustums -> (P, where the points came from)."""
    if points is not None:
        pts, cols = read_points(points)
        points_source = _relative(Path(points), out_dir)
    else:
        train_cams = [rect[n].camera for n in names if n != test_camera]
        depth = source.depth_range()
        pts, cols = frustum_points(train_cams, depth), None
        points_source = "frustum_random"
    np.save(out_dir / "points.npy", pts)
    if cols is not None:
        np.save(out_dir / "point_colors.npy", cols)
    elif (out_dir / "point_colors.npy").exists():
        (out_dir / "point_colors.npy").unlink()
    return len(pts), points_source


def _relative(path: Path, out_dir: Path) -> str:
    """``path`` relative to the prepared folder (POSIX separators): the manifest stays true when
    the folders move together, and the same inputs give the same bytes."""
    return Path(os.path.relpath(Path(path).resolve(), Path(out_dir).resolve())).as_posix()


def _write_json(path: Path, obj) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(obj, indent=1))
    os.replace(tmp, path)
