"""A capture as the nerfies/HyperNeRF capture notebook writes it.

``dataset.json`` (ids; val_ids is the layout's test split), ``metadata.json`` (time_id /
warp_id per item), ``scene.json`` (center, scale: the world normalisation, as for the
benchmarks), ``camera/<id>.json`` at 1x, ``rgb/<s>x/<id>.png``, and the initial points:
``points.npy`` when the notebook wrote it, else COLMAP's ``colmap/sparse/0/points3D`` (the
camera files are in COLMAP's world frame, so the same normalisation applies). Images in
``rgb/<s>x`` with no id in dataset.json (frames the notebook dropped) are ignored and counted.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmark.captures.common import (
    CaptureLayout,
    capture_scene,
    closest_copy,
    colmap_points,
    order_times,
    read_colmap_model,
)
from benchmark.captures.options import CaptureOptions
from benchmark.datasets.errors import fail
from benchmark.datasets.images import IMAGE_SUFFIXES
from benchmark.datasets.jsonio import field, finite_array, finite_float, read_json
from benchmark.datasets.nerfies import id_list, item_times, nerfies_view
from benchmark.datasets.points import read_points

DEFAULT_SCALE = 2  # rgb/2x: the resolution the nerfies benchmarks train on
FILES = ("dataset.json", "metadata.json", "scene.json")


def detect(scene_dir: Path) -> bool:
    return (scene_dir / "dataset.json").is_file() and (scene_dir / "camera").is_dir()


def load(scene_dir: Path, options: CaptureOptions):
    notices: list[str] = []
    ds_path, meta_path, scene_path = (scene_dir / n for n in FILES)
    dataset = read_json(ds_path, "dataset.json")
    scene_json = read_json(scene_path, "scene.json")
    center = finite_array(field(scene_json, "center", scene_path), scene_path, "center", (3,))
    scale = finite_float(field(scene_json, "scale", scene_path), scene_path, "scale")
    if scale <= 0:
        raise fail(scene_path, f"scale must be positive, got {scale}")
    ids = id_list(dataset, "ids", ds_path)
    if len(set(ids)) != len(ids):
        raise fail(ds_path, "ids lists an item twice")

    s = options.image_scale or DEFAULT_SCALE
    have = {int(p.name[:-1]): p for p in (scene_dir / "rgb").glob("*x") if p.is_dir() and p.name[:-1].isdigit()}
    s_read, image_dir = closest_copy(s, have, scene_dir / "rgb" / f"{s}x", f"image folder rgb/{s}x")
    listed = set(ids)
    unlisted = sorted(p.name for p in image_dir.iterdir() if p.suffix in IMAGE_SUFFIXES and p.stem not in listed)
    if unlisted:
        notices.append(f"ignored {len(unlisted)} image(s) in rgb/{image_dir.name} with no id in dataset.json "
                       f"(e.g. {unlisted[0]})")

    if options.time == "static":
        times = {i: (0, 0.0) for i in ids}
    elif options.time == "order":
        times = order_times(ids)
    else:
        metadata = read_json(meta_path, "metadata.json")
        if not isinstance(metadata, dict):
            raise fail(meta_path, "top level is not a JSON object")
        times = item_times(ids, metadata, meta_path)

    built = [nerfies_view(scene_dir, item, image_dir, s_read, center, scale, times[item]) for item in ids]
    views = [v for v, _ in built]
    dropped = max((px for _, px in built), default=0.0)
    if dropped > 0:
        notices.append(f"lens distortion dropped (as the public code does): up to {dropped:.2f} px at rgb/{image_dir.name}")

    points, colors = _points(scene_dir)
    points = (points - center) * scale
    val = dataset.get("val_ids", []) if isinstance(dataset, dict) else []
    return capture_scene(scene_dir, views, options, set(val) if isinstance(val, list) else set(),
                         points, colors, notices, {"scene_json": scene_json, "image_scale": s,
                                                   "scale_on_the_fly": (s / s_read, f"rgb/{s_read}x")})


def _points(scene_dir: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """points.npy, else COLMAP's sparse points (both in the camera files' world frame)."""
    npy = scene_dir / "points.npy"
    if npy.is_file():
        return read_points(npy)
    sparse = scene_dir / "colmap" / "sparse" / "0"
    if not sparse.is_dir():
        raise fail(npy, "no initial points: neither points.npy nor colmap/sparse/0 (COLMAP's points3D)")
    return colmap_points(read_colmap_model(sparse), sparse)


LAYOUT = CaptureLayout("dataset.json + camera/ + rgb/<s>x/", detect, load)
