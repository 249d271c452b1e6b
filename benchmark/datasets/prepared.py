"""Loader for what ``trase-bench prepare`` wrote, and the multi-view view builder it shares
with the transforms_*.json loader."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from benchmark.datasets.errors import fail
from benchmark.datasets.images import check_size
from benchmark.datasets.jsonio import field, read_json
from benchmark.datasets.points import read_points
from benchmark.datasets.registry import DatasetSpec
from benchmark.datasets.scene import Scene, View
from trase.camera import Camera, CameraError


def multiview_views(
    spec: DatasetSpec,
    cameras: dict[str, tuple[Camera, Camera | None]],
    frames: list[int],
    image_of: Callable[[str, int], Path],
    source: Path,
) -> tuple[list[View], list[View]]:
    """Views over cameras x frames; test = the registry's test camera, times t = i / n.

    Names are ``<camera>/<frame:05d>`` (publisher frame numbers); ``View.frame`` is i. Test
    views are ordered by frame, so ground-truth index k is the k-th frame of the range.
    """
    if spec.test_camera not in cameras:
        raise fail(source, f"test camera {spec.test_camera} is missing (cameras: {', '.join(sorted(cameras)[:4])} ...)")
    n = len(frames)
    train, test = [], []
    for name in sorted(cameras):
        cam, native = cameras[name]
        for i, fr in enumerate(frames):
            t = spec.time_of(i, n)
            img = image_of(name, fr)
            check_size(img, cam.width, cam.height, f"camera {name} in {source.name}")
            view = View(name=f"{name}/{fr:05d}", camera=cam.with_time(t), image_path=img, frame=i,
                        native_camera=native.with_time(t) if native is not None else None)
            (test if name == spec.test_camera else train).append(view)
    return train, test


def load_prepared(spec: DatasetSpec, pdir: Path, sequence: str) -> Scene:
    mpath = pdir / "prepared.json"
    manifest = read_json(mpath, "prepared.json")
    if field(manifest, "dataset", mpath) != spec.key:
        raise fail(mpath, f"prepared for dataset {manifest['dataset']!r}, not {spec.key!r}")
    frames = [int(f) for f in field(manifest, "frames", mpath)]
    if not frames:
        raise fail(mpath, "lists no frames")
    cpath = pdir / "cameras.json"
    entries = read_json(cpath, "cameras.json")
    if not isinstance(entries, list):
        raise fail(cpath, "expected a JSON list of cameras")
    cameras: dict[str, tuple[Camera, Camera | None]] = {}
    for e in entries:
        name = str(field(e, "name", cpath))
        try:
            cam = Camera.from_dict(field(e, "camera", cpath, name))
            native = Camera.from_dict(e["native"]) if e.get("native") else None
        except (CameraError, KeyError, TypeError, ValueError) as exc:
            raise fail(cpath, f"camera {name!r}: {exc}") from None
        if not cam.is_pinhole:
            raise fail(cpath, f"camera {name!r}: training camera must be an undistorted pinhole")
        cameras[name] = (cam, native)
    train, test = multiview_views(spec, cameras, frames, lambda c, f: pdir / "images" / c / f"{f:05d}.png", pdir)
    pts, cols = read_points(pdir / "points.npy")
    if (pdir / "point_colors.npy").is_file():
        cols, _ = read_points(pdir / "point_colors.npy")
        if len(cols) != len(pts):
            raise fail(pdir / "point_colors.npy", f"{len(cols)} colours for {len(pts)} points")
    return Scene(dataset=spec.key, sequence=sequence, root=pdir, train=train, test=test, points=pts,
                 point_colors=cols, extras={"format": "prepared", "prepared_dir": str(pdir),
                                            "points_source": manifest.get("points_source")})
