"""A COLMAP folder: ``images/`` (or ``images_<s>/`` at 1/s size) and ``sparse/0/`` (or
``sparse/``) with cameras, images and points3D, binary or text, as COLMAP writes them.

Cameras: PINHOLE and SIMPLE_PINHOLE as they are; SIMPLE_RADIAL, RADIAL and OPENCV with their
lens distortion dropped (the largest displacement is reported; run ``colmap
image_undistorter`` for exact geometry); other models are an error. Time: ``times.json``
(``{"<image name>": t}``, any unit, mapped to [0, 1] by (t - min) / (max - min)) when present,
else the frame order (image names sorted); ``--set capture.time=static`` for a static scene.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmark.captures.common import (
    CaptureLayout,
    capture_scene,
    closest_copy,
    colmap_points,
    normalize_scene,
    order_times,
    read_colmap_model,
    times_from_values,
)
from benchmark.captures.options import CaptureOptions
from benchmark.datasets.errors import fail
from benchmark.datasets.images import check_size, find_image
from benchmark.datasets.jsonio import finite_float, read_json
from benchmark.datasets.nerfies import distortion_px
from benchmark.datasets.scene import View
from trase.camera import Camera, CameraError

# COLMAP model name -> (fx, fy, cx, cy, k1, k2, p1, p2) from its params
_MODELS = {
    "SIMPLE_PINHOLE": lambda p: (p[0], p[0], p[1], p[2], 0, 0, 0, 0),
    "PINHOLE": lambda p: (p[0], p[1], p[2], p[3], 0, 0, 0, 0),
    "SIMPLE_RADIAL": lambda p: (p[0], p[0], p[1], p[2], p[3], 0, 0, 0),
    "RADIAL": lambda p: (p[0], p[0], p[1], p[2], p[3], p[4], 0, 0),
    "OPENCV": lambda p: (p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]),
}
TIMES = "times.json"


def sparse_dir(scene_dir: Path) -> Path | None:
    for d in (scene_dir / "sparse" / "0", scene_dir / "sparse"):
        if any((d / f"cameras{ext}").is_file() for ext in (".bin", ".txt")):
            return d
    return None


def detect(scene_dir: Path) -> bool:
    return sparse_dir(scene_dir) is not None and any(scene_dir.glob("images*"))


def camera_of(model_camera, w2c: np.ndarray, name: str, where: Path) -> Camera:
    """A pycolmap camera and pose -> ``Camera`` at the model's (native) size."""
    kind = model_camera.model.name
    if kind not in _MODELS:
        raise fail(where, f"camera {model_camera.camera_id} has model {kind}; supported: "
                          f"{', '.join(_MODELS)} (run colmap image_undistorter first)")
    fx, fy, cx, cy, k1, k2, p1, p2 = (float(x) for x in _MODELS[kind](list(model_camera.params)))
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    try:
        return Camera(K=K, w2c=w2c, width=int(model_camera.width), height=int(model_camera.height), name=name,
                      radial=(k1, k2, 0.0), tangential=(p1, p2))
    except CameraError as exc:
        raise fail(where, str(exc)) from None


def _times(scene_dir: Path, names: list[str], options: CaptureOptions, notices: list[str]) -> dict:
    path = scene_dir / TIMES
    if options.time == "static":
        return {n: (0, 0.0) for n in names}
    if options.time == "auto" and path.is_file():
        raw = read_json(path, TIMES)
        if not isinstance(raw, dict):
            raise fail(path, 'top level must be an object {"<image name>": time}')
        missing = [n for n in names if n not in raw]
        if missing:
            raise fail(path, f"no time for {len(missing)} image(s) (e.g. {missing[0]!r})")
        t = {n: finite_float(raw[n], path, f"time of {n!r}") for n in names}
        notices.append(f"time from {TIMES}: {len(set(t.values()))} distinct times")
        return times_from_values(t)
    notices.append("time from the frame order (image names sorted); give times.json for another rule")
    return order_times(names)


def load(scene_dir: Path, options: CaptureOptions):
    notices: list[str] = []
    sparse = sparse_dir(scene_dir)
    if sparse is None:
        raise fail(scene_dir / "sparse" / "0", "no COLMAP model (cameras.bin or cameras.txt)")
    model = read_colmap_model(sparse)
    s = options.image_scale or 1
    have = {1 if p.name == "images" else int(p.name[7:]): p for p in scene_dir.glob("images*")
            if p.is_dir() and (p.name == "images" or (p.name.startswith("images_") and p.name[7:].isdigit()))}
    s_read, image_dir = closest_copy(s, have, scene_dir / ("images" if s == 1 else f"images_{s}"), "image folder")
    images = sorted(model.images.values(), key=lambda im: im.name)
    if not images:
        raise fail(sparse, "the COLMAP model has no registered images")
    times = _times(scene_dir, [im.name for im in images], options, notices)
    dropped = 0.0
    views = []
    for im in images:
        w2c = np.eye(4)
        w2c[:3, :] = np.asarray(im.cam_from_world().matrix(), np.float64)
        native = camera_of(model.cameras[im.camera_id], w2c, im.name, sparse)
        frame, t = times[im.name]
        native = native.with_time(t)
        cam = native.scaled(s_read).undistorted()
        dropped = max(dropped, distortion_px(native) / s_read)
        img = find_image(image_dir, im.name)
        check_size(img, cam.width, cam.height, f"COLMAP camera {im.camera_id} scaled 1/{s_read}")
        views.append(View(name=Path(im.name).with_suffix("").as_posix(), camera=cam, image_path=img,
                          frame=frame, native_camera=native))
    if dropped > 0:
        notices.append(f"lens distortion dropped: up to {dropped:.2f} px (run colmap image_undistorter for exact geometry)")
    points, colors = colmap_points(model, sparse)
    scene = capture_scene(scene_dir, views, options, set(), points, colors, notices,
                          {"image_scale": s, "scale_on_the_fly": (s / s_read, image_dir.name)})
    return normalize_scene(scene, options, notices)


LAYOUT = CaptureLayout("images/ + sparse/0/ (COLMAP)", detect, load)
