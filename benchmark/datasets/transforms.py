"""The layout the paper's public code writes for Neu3D, Immersive and Technicolor
(``*2blender.py``): ``transforms_train.json``, ``transforms_test.json``, ``images_2x/*.png``,
``points3d.ply``. Read as is, so users of that code can point this toolkit at what they have.

Facts of that layout:

* Neu3D: intrinsics at the top level (``w h fl_x fl_y cx cy``); ``transform_matrix`` is a
  camera-to-world pose in OpenGL/Blender axes (y up, z back) in a recentred, rescaled world.
* Immersive, Technicolor: intrinsics per frame; ``transform_matrix`` is world-to-camera in
  OpenCV axes. Images are already undistorted with the principal point centred.
* ``file_path`` is ``images_2x/<camera>_<frame:04d>`` (no extension; .png).
* ``time`` there is seconds (frame / 30); this loader ignores it and applies the registry's
  rule t = i / n over the benchmark's frame range (which the public reader reproduces).

The test camera comes from the registry, not from which file a frame is listed in.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from benchmark.datasets.errors import fail
from benchmark.datasets.jsonio import field, finite_array, finite_float, read_json
from benchmark.datasets.points import read_points
from benchmark.datasets.prepared import multiview_views
from benchmark.datasets.registry import DatasetSpec
from benchmark.datasets.scene import Scene
from trase.camera import Camera, CameraError

_PATH = re.compile(r"^(?P<cam>.+)_(?P<frame>\d{4,5})$")


def _camera_name(spec: DatasetSpec, raw: str) -> str:
    if spec.format == "technicolor":
        m = re.match(r"^camera_(\d+)$", raw)
        if m:
            return f"cam{int(m.group(1)):02d}"
    return raw


def _intrinsics(src: dict, path: Path, where: str) -> tuple[np.ndarray, int, int]:
    get = lambda k: finite_float(field(src, k, path, where), path, f"{k} of {where}")
    w, h = get("w"), get("h")
    if w <= 0 or h <= 0 or w != int(w) or h != int(h):
        raise fail(path, f"{where}: image size {w}x{h} is not two positive integers")
    K = np.array([[get("fl_x"), 0.0, get("cx")], [0.0, get("fl_y"), get("cy")], [0.0, 0.0, 1.0]])
    return K, int(w), int(h)


def load_transforms(spec: DatasetSpec, scene_dir: Path, sequence: str) -> Scene:
    wanted = set(spec.frames(sequence))
    cameras: dict[str, tuple[Camera, None]] = {}
    frames_of: dict[str, set[int]] = {}
    files: dict[tuple[str, int], Path] = {}
    for split in ("train", "test"):
        path = scene_dir / f"transforms_{split}.json"
        contents = read_json(path, f"transforms_{split}.json")
        for k, fr in enumerate(field(contents, "frames", path)):
            where = f"frames[{k}]"
            fp = str(field(fr, "file_path", path, where))
            m = _PATH.match(Path(fp).name)
            if not m:
                raise fail(path, f"{where}: file_path {fp!r} is not <camera>_<frame>")
            name, number = _camera_name(spec, m.group("cam")), int(m.group("frame"))
            if number not in wanted:
                continue
            mat = finite_array(field(fr, "transform_matrix", path, where), path, f"transform_matrix of {where}", (4, 4))
            if spec.format == "neu3d":
                K, W, H = _intrinsics(contents, path, "top level")
                c2w = mat.copy()
                c2w[:3, 1:3] *= -1.0  # OpenGL (y up, z back) -> OpenCV (y down, z forward)
                w2c = np.linalg.inv(c2w)
            else:
                K, W, H = _intrinsics(fr, path, where)
                w2c = mat
            try:
                cam = Camera(K=K, w2c=w2c, width=W, height=H, name=name)
            except CameraError as exc:
                raise fail(path, f"{where}: {exc}") from None
            if name in cameras and not np.allclose(cameras[name][0].w2c, cam.w2c, atol=1e-6):
                raise fail(path, f"{where}: camera {name} has different poses in different frames")
            cameras.setdefault(name, (cam, None))
            frames_of.setdefault(name, set()).add(number)
            img = scene_dir / (fp + ".png")
            files[(name, number)] = img
    if not cameras:
        raise fail(scene_dir / "transforms_train.json", f"no frame of the range {min(wanted)}..{max(wanted)}")
    frames = sorted(set().union(*frames_of.values()))
    for name, have in frames_of.items():
        if have != set(frames):
            missing = sorted(set(frames) - have)
            raise fail(scene_dir / "transforms_train.json", f"camera {name} lacks frame(s) {missing[:5]}")
    train, test = multiview_views(spec, cameras, frames, lambda c, f: files[(c, f)], scene_dir / "transforms_train.json")
    pts, cols = read_points(scene_dir / "points3d.ply")
    return Scene(dataset=spec.key, sequence=sequence, root=scene_dir, train=train, test=test,
                 points=pts, point_colors=cols,
                 extras={"format": "transforms", "points_source": str(scene_dir / "points3d.ply")})
