"""A loaded scene written as a capture in each layout the readers take: for the tests' fixtures,
the capture figures (``trase-bench perf captures``) and anyone converting a scene.

Each writer takes the views to write and puts them in the layout as its tool would: the
nerfies notebook's folders with COLMAP's sparse points in the camera files' frame (written by
pycolmap, in the legacy three-file layout of COLMAP 3.x that the notebook runs), a COLMAP
folder with ``times.json``, and transforms json with ``points3d.ply``.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from benchmark.captures.transforms import GL_TO_CV
from benchmark.datasets.synthetic.formats import downscale, write_json, write_png, write_points_ply
from imagefiles import read_rgb8


def _colors(points: np.ndarray, colors: np.ndarray | None) -> np.ndarray:
    return np.full((len(points), 3), 0.5) if colors is None else np.asarray(colors, np.float64)


def write_colmap_model(out: Path, views, points: np.ndarray, colors: np.ndarray | None,
                       to_raw=lambda p: p, legacy: bool = True) -> Path:
    """cameras/images/points3D.bin of ``views`` (PINHOLE, one camera per distinct
    intrinsics) with points mapped by ``to_raw``; ``legacy``: without COLMAP 4's rigs/frames."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    cam_ids: dict[tuple, int] = {}
    for k, v in enumerate(views, start=1):
        c = v.camera
        key = (c.width, c.height, *np.round(c.K[[0, 1, 0, 1], [0, 1, 2, 2]], 9))
        if key not in cam_ids:
            cam_ids[key] = len(cam_ids) + 1
            rec.add_camera_with_trivial_rig(pycolmap.Camera(
                model="PINHOLE", width=c.width, height=c.height, camera_id=cam_ids[key],
                params=[c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2]]))
        R = c.w2c[:3, :3]
        t = -R @ to_raw(c.center)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(R), t)
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f"{v.name}.png", camera_id=cam_ids[key], image_id=k), pose)
    rgb = np.clip(np.round(_colors(points, colors) * 255), 0, 255).astype(np.uint8)
    for p, c in zip(to_raw(points), rgb):
        rec.add_point3D(np.asarray(p, np.float64), pycolmap.Track(), c)
    out.mkdir(parents=True, exist_ok=True)
    rec.write_binary(str(out))
    if legacy:
        for name in ("rigs.bin", "frames.bin"):
            (out / name).unlink(missing_ok=True)
    return out


def write_nerfies_capture(views, points, colors, out: Path | str, *, center=(0.25, -0.5, 0.125),
                          scale: float = 0.5, unlisted=(), with_points_npy: bool = False) -> Path:
    """A nerfies capture (rgb/2x = the views' images, rgb/4x, camera/ at 1x, COLMAP points in
    the raw frame; scene.json's ``center``/``scale`` map raw to the views' frame). ``unlisted``
    views get an image but no id, as frames the notebook dropped."""
    out = Path(out)
    center = np.asarray(center, np.float64)

    def to_raw(p):
        return np.asarray(p) / scale + center

    write_json(out / "scene.json", {"scale": scale, "center": center.tolist(), "near": 0.01, "far": 10.0})
    ids = [v.name for v in views]
    write_json(out / "dataset.json", {"count": len(ids), "num_exemplars": len(ids), "ids": ids,
                                      "train_ids": ids, "val_ids": []})
    write_json(out / "metadata.json", {v.name: {"time_id": int(v.frame), "warp_id": int(v.frame),
                                                "appearance_id": int(v.frame), "camera_id": 0} for v in views})
    for v in list(views) + list(unlisted):
        c = v.camera
        rgb = read_rgb8(v.image_path)
        write_png(out / "rgb" / "2x" / f"{v.name}.png", rgb)
        write_png(out / "rgb" / "4x" / f"{v.name}.png", downscale(rgb, 2))
        if v in unlisted:
            continue
        write_json(out / "camera" / f"{v.name}.json", {
            "orientation": c.w2c[:3, :3].tolist(), "position": to_raw(c.center).tolist(),
            "focal_length": float(c.K[0, 0] * 2), "principal_point": (c.K[:2, 2] * 2).tolist(),
            "skew": 0.0, "pixel_aspect_ratio": float(c.K[1, 1] / c.K[0, 0]),
            "radial_distortion": [0.0, 0.0, 0.0], "tangential_distortion": [0.0, 0.0],
            "image_size": [c.width * 2, c.height * 2]})
    write_colmap_model(out / "colmap" / "sparse" / "0", views, points, colors, to_raw)
    if with_points_npy:
        np.save(out / "points.npy", to_raw(points))
    return out


def write_colmap_folder(views, points, colors, out: Path | str, *, with_times: bool = True) -> Path:
    """images/ + sparse/0 (+ times.json: image name -> the view's time)."""
    out = Path(out)
    for v in views:
        (out / "images").mkdir(parents=True, exist_ok=True)
        write_png(out / "images" / f"{v.name}.png", read_rgb8(v.image_path))
    write_colmap_model(out / "sparse" / "0", views, points, colors)
    if with_times:
        write_json(out / "times.json", {f"{v.name}.png": float(v.time) for v in views})
    return out


def write_transforms(views, points, colors, out: Path | str, test_views=()) -> Path:
    """transforms_train.json (+ transforms_test.json for ``test_views``), images/, points3d.ply."""
    out = Path(out)

    def doc(vs):
        frames = []
        for v in vs:
            c = v.camera
            write_png(out / "images" / f"{v.name}.png", read_rgb8(v.image_path))
            frames.append({"file_path": f"./images/{v.name}", "time": float(v.time),
                           "fl_x": float(c.K[0, 0]), "fl_y": float(c.K[1, 1]), "cx": float(c.K[0, 2]),
                           "cy": float(c.K[1, 2]), "w": c.width, "h": c.height,
                           "transform_matrix": (c.c2w @ GL_TO_CV).tolist()})
        return {"frames": frames}

    write_json(out / "transforms_train.json", doc(views))
    if test_views:
        write_json(out / "transforms_test.json", doc(test_views))
    write_points_ply(out / "points3d.ply", np.asarray(points), _colors(points, colors))
    return out


def clear(out: Path | str) -> None:
    shutil.rmtree(out, ignore_errors=True)
