"""The nerfies format of HyperNeRF and NeRF-DS.

Layout: ``dataset.json`` (ids, train_ids, val_ids), ``metadata.json`` (item -> time_id,
warp_id, camera_id), ``scene.json`` (scale, center, near, far), ``camera/<item>.json``,
``rgb/{1,2,4}x/<item>.png``, ``points.npy``.

Camera file: ``orientation`` = world-to-camera rotation (rows are the camera axes),
``position`` = camera centre, ``focal_length``, ``principal_point``, ``skew``,
``pixel_aspect_ratio``, ``radial_distortion`` (k1, k2, k3), ``tangential_distortion`` (p1, p2;
older files call it ``tangential``), ``image_size`` [W, H] at 1x. Pixel model on distorted
normalised coordinates: u = f xd + skew yd + cx, v = f * aspect * yd + cy.

World frame: like the public code, positions and points are normalised with scene.json,
``(p - center) * scale`` (a similarity transform, so projections do not change).

Views: the benchmark's ground truth was drawn on the publisher's ``rgb/2x`` images, so the
views are those images, unresampled; their pinhole camera keeps the file's focal length,
aspect ratio, skew and principal point and drops the (small) lens distortion, as the public
code does. The largest pixel displacement that this drops is recorded in
``scene.extras["distortion_dropped_px"]``; ``View.native_camera`` keeps the full model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmark.datasets.errors import fail
from benchmark.datasets.images import check_size, find_image
from benchmark.datasets.jsonio import field, finite_array, finite_float, read_json
from benchmark.datasets.registry import DatasetSpec, nerfies_time
from benchmark.datasets.scene import Scene, View
from trase.camera import Camera, CameraError


def read_camera(path: Path | str) -> Camera:
    """A nerfies camera file -> ``Camera`` at native (1x) resolution with the full lens model.

    The pose is as stored (no scene.json normalisation); time is 0.
    """
    path = Path(path)
    d = read_json(path, "camera file")
    R = finite_array(field(d, "orientation", path), path, "orientation", (3, 3))
    c = finite_array(field(d, "position", path), path, "position", (3,))
    f = finite_float(field(d, "focal_length", path), path, "focal_length")
    pp = finite_array(field(d, "principal_point", path), path, "principal_point", (2,))
    skew = finite_float(d.get("skew", 0.0), path, "skew")
    aspect = finite_float(d.get("pixel_aspect_ratio", 1.0), path, "pixel_aspect_ratio")
    size = finite_array(field(d, "image_size", path), path, "image_size", (2,))
    radial = finite_array(d.get("radial_distortion", [0.0, 0.0, 0.0]), path, "radial_distortion")
    tangential_raw = d.get("tangential_distortion", d.get("tangential", [0.0, 0.0]))
    tangential = finite_array(tangential_raw, path, "tangential_distortion", (2,))
    if radial.ndim != 1 or not 1 <= radial.size <= 3:
        raise fail(path, f"radial_distortion must hold 1 to 3 values, got {radial.size}")
    radial = np.concatenate([radial, np.zeros(3 - radial.size)])
    if size[0] <= 0 or size[1] <= 0 or size[0] != int(size[0]) or size[1] != int(size[1]):
        raise fail(path, f"image_size must be two positive integers [W, H], got {size.tolist()}")
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ c
    K = np.array([[f, skew, pp[0]], [0.0, f * aspect, pp[1]], [0.0, 0.0, 1.0]])
    try:
        return Camera(
            K=K, w2c=w2c, width=int(size[0]), height=int(size[1]), name=path.stem,
            radial=tuple(radial), tangential=tuple(tangential),
        )
    except CameraError as exc:
        raise fail(path, str(exc)) from None


def normalise_pose(cam: Camera, center: np.ndarray, scale: float) -> Camera:
    """The same camera in the scene.json-normalised world ``(p - center) * scale``."""
    import dataclasses

    R = cam.w2c[:3, :3]
    c = (cam.center - center) * scale
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ c
    return dataclasses.replace(cam, w2c=w2c)


def item_times(dataset_ids: list[str], metadata: dict, path: Path) -> dict[str, tuple[int, float]]:
    """item id -> (time id, normalised time) over all items of dataset.json."""
    ids_raw: dict[str, float] = {}
    for item in dataset_ids:
        meta = metadata.get(item)
        if meta is None:
            raise fail(path, f"no entry for item {item!r}")
        tid = meta.get("time_id", meta.get("warp_id"))
        if tid is None:
            raise fail(path, f"item {item!r} has neither time_id nor warp_id")
        ids_raw[item] = finite_float(tid, path, f"time_id of {item!r}")
    max_t = max(ids_raw.values(), default=0.0)
    return {k: (int(v), nerfies_time(v, max_t)) for k, v in ids_raw.items()}


def id_list(dataset: dict, key: str, path: Path) -> list[str]:
    """``dataset[key]`` as a list of item ids (strings), or an error naming the file."""
    value = field(dataset, key, path)
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise fail(path, f"{key} must be a list of item id strings, got {type(value).__name__}")
    return list(value)


def split_ids(spec: DatasetSpec, dataset: dict, path: Path) -> tuple[list[str], list[str]]:
    """Train and test item ids by the registry's rule (never by folder name)."""
    if spec.key == "hypernerf":
        ids = id_list(dataset, "ids", path)
        return ids[0::4], ids[2::4]
    if spec.key == "nerfds":
        return id_list(dataset, "train_ids", path), id_list(dataset, "val_ids", path)
    raise fail(path, f"dataset {spec.key} is not in the nerfies format")


def nerfies_view(scene_dir: Path, item: str, image_dir: Path, downscale: int, center: np.ndarray, scale: float,
                 time: tuple[int, float]) -> tuple[View, float]:
    """One item's view: ``camera/<item>.json`` normalised by scene.json, at ``time`` (frame,
    t), scaled to the images of ``image_dir`` (1/downscale) with the lens distortion dropped,
    -> (view, the largest displacement dropped, in those images' pixels)."""
    native = normalise_pose(read_camera(scene_dir / "camera" / f"{item}.json"), center, scale)
    frame, t = time
    native = native.with_time(t)
    cam = native.scaled(downscale).undistorted()
    img = find_image(image_dir, item)
    check_size(img, cam.width, cam.height, f"camera/{item}.json scaled 1/{downscale}")
    return View(name=item, camera=cam, image_path=img, frame=frame, native_camera=native), distortion_px(native) / downscale


def load_nerfies(spec: DatasetSpec, scene_dir: Path, sequence: str) -> Scene:
    ds_path, meta_path, scene_path = (scene_dir / n for n in ("dataset.json", "metadata.json", "scene.json"))
    dataset = read_json(ds_path, "dataset.json")
    metadata = read_json(meta_path, "metadata.json")
    scene_json = read_json(scene_path, "scene.json")
    if not isinstance(metadata, dict):
        raise fail(meta_path, "top level is not a JSON object")
    center = finite_array(field(scene_json, "center", scene_path), scene_path, "center", (3,))
    scale = finite_float(field(scene_json, "scale", scene_path), scene_path, "scale")
    if scale <= 0:
        raise fail(scene_path, f"scale must be positive, got {scale}")

    all_ids = id_list(dataset, "ids", ds_path)
    train_ids, test_ids = split_ids(spec, dataset, ds_path)
    for item in train_ids + test_ids:
        if item not in all_ids:
            raise fail(ds_path, f"split item {item!r} is not listed in ids")
    times = item_times(all_ids, metadata, meta_path)

    image_dir = scene_dir / "rgb" / f"{spec.downscale}x"
    if not image_dir.is_dir():
        raise fail(image_dir, f"missing image folder rgb/{spec.downscale}x")
    built = {i: nerfies_view(scene_dir, i, image_dir, spec.downscale, center, scale, times[i])
             for i in train_ids + test_ids}
    train, test = [built[i][0] for i in train_ids], [built[i][0] for i in test_ids]
    dropped = max((px for _, px in built.values()), default=0.0)
    pts_path = scene_dir / "points.npy"
    if not pts_path.is_file():
        raise fail(pts_path, "missing initial point cloud points.npy")
    try:
        pts = np.load(pts_path)
    except (ValueError, OSError) as exc:
        raise fail(pts_path, f"cannot read ({exc.__class__.__name__})") from None
    pts = finite_array(pts, pts_path, "points")
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise fail(pts_path, f"points must be [N, 3], got shape {pts.shape}")
    return Scene(
        dataset=spec.key, sequence=sequence, root=scene_dir, train=train, test=test,
        points=(pts - center) * scale,
        extras={"scene_json": scene_json, "format": "nerfies", "distortion_dropped_px": dropped},
    )


def distortion_px(cam: Camera) -> float:
    """Largest displacement (native pixels) the lens model applies inside the image."""
    if cam.is_pinhole:
        return 0.0
    u = np.linspace(0.0, cam.width, 9)
    v = np.linspace(0.0, cam.height, 9)
    uu, vv = np.meshgrid(u, v)
    uv = np.stack([uu.ravel(), vv.ravel()], axis=1)
    y = (uv[:, 1] - cam.cy) / cam.fy
    x = (uv[:, 0] - cam.cx - cam.K[0, 1] * y) / cam.fx
    xy = np.stack([x, y], axis=1)
    d = cam.distort(xy) - xy
    return float(np.max(np.hypot(d[:, 0] * cam.fx, d[:, 1] * cam.fy)))
