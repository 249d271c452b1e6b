"""Run a generator over the training views of a scene and fill a mask store.

``views`` are duck-typed: anything with ``.name`` and ``.image_path`` (the benchmark's
``View``). One file per view at ``mask_path(out_dir, view.name)``; a view whose file already
holds masks from the same generator is skipped, so an interrupted run resumes where it
stopped (writes are atomic, a half-written file never exists).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from imagefiles import read_rgb8
from masks.maskset import MaskError
from masks.store import MaskFileError, mask_path, read_header, save


class ImageReadError(MaskError):
    user_facing = True


def read_instance_map(path: os.PathLike | str) -> np.ndarray:
    """[H, W] int64 instance ids from a single-channel (uint8/uint16) PNG."""
    import cv2

    ids = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if ids is None:
        raise ImageReadError(f"{path}: cannot read instance map")
    if ids.ndim != 2:
        raise ImageReadError(f"{path}: instance map must be single-channel, got shape {ids.shape}")
    return ids.astype(np.int64)


def _done(path: Path, generator_name: str) -> bool:
    """True when ``path`` already holds masks from ``generator_name``."""
    if not path.exists():
        return False
    try:
        header = read_header(path)
    except MaskFileError:
        return False  # damaged: regenerate it
    if header["generator"] != generator_name:
        raise MaskError(f"{path}: already holds masks from generator {header['generator']!r}, "
                        f"not {generator_name!r}; choose another output folder")
    return True


def generate_scene_masks(
    views: Iterable,
    generator,
    out_dir: os.PathLike | str,
    progress: bool = True,
    instance_maps: dict | None = None,
    background=None,
) -> list[Path]:
    """Masks for every view, one file each; returns the paths in view order.

    ``instance_maps``: view name -> [H, W] int array or path of an instance-id PNG; required
    (for every view) by generators with ``needs_instance_map``. ``background``: what an RGBA
    image is composited over (imagefiles' rule; the reconstruction's background, default black),
    so masks are cut from the picture the reconstruction trains on.
    """
    views = list(views)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    needs_ids = bool(getattr(generator, "needs_instance_map", False))
    if needs_ids:
        missing = [v.name for v in views if not instance_maps or v.name not in instance_maps]
        if missing:
            raise MaskError(f"generator {generator.name!r} needs instance maps; none for "
                            f"{len(missing)} view(s), e.g. {missing[0]!r}")
    paths = [mask_path(out_dir, v.name) for v in views]
    todo = [(v, p) for v, p in zip(views, paths) if not _done(p, generator.name)]

    bar = None
    if progress and todo:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        bar = Progress(TextColumn("masks ({task.fields[gen]})"), BarColumn(), MofNCompleteColumn(),
                       TimeElapsedColumn(), TimeRemainingColumn(), TextColumn("{task.fields[last]}"))
        task = bar.add_task("masks", total=len(todo), gen=generator.name, last="")
        bar.start()
    try:
        for view, path in todo:
            t0 = time.perf_counter()
            image = read_rgb8(view.image_path, background) if not needs_ids else None
            ids = None
            if needs_ids:
                ids = instance_maps[view.name]
                if not isinstance(ids, np.ndarray):
                    ids = read_instance_map(ids)
            ms = generator.generate(image, key=view.name, instance_map=ids)
            ms.info.update({"view": view.name, "image": Path(view.image_path).name,
                            "seconds": round(time.perf_counter() - t0, 4)})
            save(path, ms)
            if bar is not None:
                bar.update(task, advance=1, last=f"{view.name}: {ms.n} masks")
    finally:
        if bar is not None:
            bar.stop()
    return paths
