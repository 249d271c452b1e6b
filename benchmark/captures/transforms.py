"""``transforms_train.json`` (+ ``transforms_test.json``), the layout of the paper's public
code (after D-NeRF): intrinsics as ``camera_angle_x`` or ``fl_x``/``fl_y``/``cx``/``cy``
(top level or per frame; ``w``/``h`` else the image's size), each frame's ``file_path``
(relative to the file, extension optional) and ``transform_matrix`` (camera-to-world in
OpenGL axes: x right, y up, z back), and ``time`` per frame (mapped to [0, 1] when it is not
there already; the frame order when absent). Initial points: ``points3d.ply`` (what the public
code writes), ``points3D.ply`` or ``fused.ply``; without one, random points where the cameras
look (``common.points_in_view``), said in a notice. The frames of transforms_test.json are
the layout's test views (``--holdout layout``); by default they train too.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from benchmark.captures.common import (
    CaptureLayout,
    capture_scene,
    normalize_scene,
    order_times,
    points_from_alpha,
    points_in_view,
    times_from_values,
)
from benchmark.captures.options import CaptureOptions
from benchmark.datasets.errors import fail
from benchmark.datasets.images import find_image, image_size
from benchmark.datasets.jsonio import field, finite_array, finite_float, read_json
from benchmark.datasets.points import read_points
from benchmark.datasets.scene import View
from trase.camera import Camera, CameraError

FILES = ("transforms_train.json", "transforms_test.json")
VAL_FILE = "transforms_val.json"  # D-NeRF's validation split: read, never trained on
POINT_FILES = ("points3d.ply", "points3D.ply", "fused.ply")
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])  # camera axes: OpenGL (y up, z back) -> OpenCV


def detect(scene_dir: Path) -> bool:
    return (scene_dir / FILES[0]).is_file()


def _frames(path: Path) -> tuple[dict, list[dict]]:
    doc = read_json(path, path.name)
    frames = field(doc, "frames", path)
    if not isinstance(frames, list) or not frames or not all(isinstance(f, dict) for f in frames):
        raise fail(path, "frames must be a non-empty list of objects")
    return doc, frames


def _camera(doc: dict, frame: dict, image: Path, path: Path, where: str, scale: int) -> Camera:
    """The frame's pinhole camera (its own keys first, then the file's) for an image at 1/scale."""
    def get(key):
        return frame.get(key, doc.get(key))

    c2w = finite_array(field(frame, "transform_matrix", path, where), path, f"transform_matrix of {where}", (4, 4))
    if get("w") is not None and get("h") is not None:
        w = int(finite_float(get("w"), path, "w")) // scale
        h = int(finite_float(get("h"), path, "h")) // scale
    else:
        w, h = image_size(image)
        scale = 1  # intrinsics are taken to be the image's own
    if get("fl_x") is not None:
        fx = finite_float(get("fl_x"), path, "fl_x") / scale
        fy = finite_float(get("fl_y") if get("fl_y") is not None else get("fl_x"), path, "fl_y") / scale
    elif get("camera_angle_x") is not None:
        angle = finite_float(get("camera_angle_x"), path, "camera_angle_x")
        if not 0 < angle < math.pi:
            raise fail(path, f"camera_angle_x must lie in (0, pi), got {angle}")
        fx = fy = 0.5 * w / math.tan(0.5 * angle)
    else:
        raise fail(path, f"no intrinsics for {where} (camera_angle_x or fl_x)")
    cx = finite_float(get("cx"), path, "cx") / scale if get("cx") is not None else w / 2
    cy = finite_float(get("cy"), path, "cy") / scale if get("cy") is not None else h / 2
    try:
        w2c = np.linalg.inv(c2w @ GL_TO_CV)
        return Camera(K=np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), w2c=w2c, width=w, height=h,
                      name=where)
    except (CameraError, np.linalg.LinAlgError) as exc:
        raise fail(path, f"{where}: {exc}") from None


def load(scene_dir: Path, options: CaptureOptions):
    notices: list[str] = []
    s = options.image_scale or 1
    s_read = s if s == 1 or _has_scaled_copy(scene_dir, s) else 1  # no copy: scaled on the fly from the listed files
    entries = []  # (file, doc, frame, name, image)
    test_names: set[str] = set()
    val_names: set[str] = set()
    for fname in (*FILES, VAL_FILE):
        path = scene_dir / fname
        if not path.is_file():
            if fname == FILES[0]:
                raise fail(path, "missing")
            continue
        doc, frames = _frames(path)
        for i, fr in enumerate(frames):
            where = f"frame {i}"
            rel = str(field(fr, "file_path", path, where)).removeprefix("./")
            if s_read > 1:  # <folder>_<s>/ beside the listed folder, as COLMAP's images_<s>
                rel = _scaled_rel(rel, s_read)
            image = find_image(scene_dir, rel)
            name = Path(rel).with_suffix("").as_posix() if Path(rel).suffix in (".png", ".jpg", ".jpeg") else rel
            entries.append((path, doc, fr, name, image, where))
            if fname == FILES[1]:
                test_names.add(name)
            elif fname == VAL_FILE:
                val_names.add(name)
    names = [e[3] for e in entries]
    if len(set(names)) != len(names):
        raise fail(scene_dir / FILES[0], "two frames name the same image")

    if options.time == "static":
        times = {n: (0, 0.0) for n in names}
    elif options.time == "auto" and all("time" in e[2] for e in entries):
        raw = {e[3]: finite_float(e[2]["time"], e[0], f"time of {e[5]}") for e in entries}
        times = times_from_values(raw, keep_unit=True)
        mapped = any(times[n][1] != v for n, v in raw.items())
        notices.append(f"time from the frames' time field{' mapped to [0, 1]' if mapped else ''}")
    else:
        times = order_times(names)
        notices.append("time from the frame order (file names sorted)")

    views = []
    for path, doc, fr, name, image, where in entries:
        cam = _camera(doc, fr, image, path, where, s_read)
        frame, t = times[name]
        cam = cam.with_time(t)
        w, h = image_size(image)
        if (w, h) != (cam.width, cam.height):
            raise fail(image, f"image is {w}x{h} but {path.name} {where} says {cam.width}x{cam.height}")
        views.append(View(name=name, camera=cam, image_path=image, frame=frame))

    _notice_unlisted([e[4] for e in entries], notices)
    if _has_alpha(views[0].image_path):
        notices.append("the images carry alpha: composited over the run's background "
                       "(geometry.train.white_background; black unless set)")
    validation = [v for v in views if v.name in val_names]
    views = [v for v in views if v.name not in val_names]
    if validation:
        notices.append(f"{len(validation)} validation views ({VAL_FILE}): never trained on, measured beside the test views")

    points, colors = None, None
    for fname in POINT_FILES:
        if (scene_dir / fname).is_file():
            points, colors = read_points(scene_dir / fname)
            break
    carve = points is None and options.initial_points == "auto" and _has_alpha(views[0].image_path)
    carved = points_from_alpha([v for v in views if v.name not in test_names]) if carve else None
    if carved is not None:
        points, colors = carved
        notices.append(f"no {' / '.join(POINT_FILES)}: {len(points)} initial points carved from the images' alpha "
                       "(inside the silhouette in at least half the views that see them, coloured by them)")
    elif points is None:
        points = points_in_view(views)
        notices.append(f"no {' / '.join(POINT_FILES)}: {len(points)} random initial points where the cameras look")
    scene = capture_scene(scene_dir, views, options, test_names, points, colors, notices,
                          {"image_scale": s, "scale_on_the_fly": (s / s_read, "the listed images")})
    scene.validation = validation
    return normalize_scene(scene, options, notices)


def _notice_unlisted(listed: list[Path], notices: list[str]) -> None:
    """Images in the listed frames' folders that no frame names (renders, depth maps, copies):
    ignored, said once per folder."""
    from benchmark.datasets.images import IMAGE_SUFFIXES

    names = {p.resolve() for p in listed}
    for folder in sorted({p.parent for p in listed}):
        stray = sorted(q.name for q in folder.iterdir() if q.suffix in IMAGE_SUFFIXES and q.resolve() not in names)
        if stray:
            notices.append(f"ignored {len(stray)} image(s) in {folder.name}/ that no frame lists (e.g. {stray[0]})")


def _has_alpha(image: Path) -> bool:
    from PIL import Image

    with Image.open(image) as im:
        return "A" in im.getbands()


def _scaled_rel(rel: str, s: int) -> str:
    """The frame's file in the copy at 1/s: ``<folder>_<s>/<rest>`` for ``<folder>/<rest>``."""
    parts = Path(rel).parts
    return str(Path(f"{parts[0]}_{s}", *parts[1:])) if len(parts) > 1 else rel


def _has_scaled_copy(scene_dir: Path, s: int) -> bool:
    """Whether the first frame's folder has a copy at 1/s beside it (``<folder>_<s>/``)."""
    _, frames = _frames(scene_dir / FILES[0])
    rel = str(field(frames[0], "file_path", scene_dir / FILES[0], "frame 0")).removeprefix("./")
    parts = Path(rel).parts
    return len(parts) > 1 and (scene_dir / f"{parts[0]}_{s}").is_dir()


LAYOUT = CaptureLayout("transforms_train.json (+ transforms_test.json)", detect, load)
