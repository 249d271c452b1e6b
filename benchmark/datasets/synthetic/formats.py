"""Writers of the publishers' raw formats (the same files the real datasets ship).

* nerfies (HyperNeRF, NeRF-DS): dataset.json, metadata.json, scene.json, camera/<id>.json,
  rgb/{1,2,4}x/<id>.png, points.npy. Positions and points are stored in the publisher's raw
  world, ``raw = world / scale + center``, so a loader that normalises with scene.json
  (``(p - center) * scale``) gets the generator's world back.
* neu3d: poses_bounds.npy ([N, 17]: 3x5 c2w in LLFF [down, right, back] axes with an
  [H, W, focal] column, then near, far; row i = i-th video in sorted order) + camNN.mp4.
* immersive: models.json (w2c rotation as axis-angle, equidistant fisheye) + camera_XXXX.mp4.
* technicolor: cameras_parameters.txt (header + ``f cu cv ar sk qw qx qy qz tx ty tz`` rows,
  COLMAP w2c) + ``<Scene>_undist_<frame:05d>_<cam:02d>.png``.

Videos are written with OpenCV's mp4v codec at 30 fps (lossy, as the real ones are).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from trase.camera import Camera

NERFIES_CENTER = np.array([0.12, -0.25, 0.05])  # scene.json center (raw world units)
NERFIES_SCALE = 0.5  # scene.json scale: normalised = (raw - center) * scale
TECHNICOLOR_SCENE = "Synthetic"
VIDEO_FPS = 30


def write_json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=2) + "\n")


def write_png(path: Path, rgb: np.ndarray) -> None:
    """RGB uint8 [H, W, 3] (or a single-channel map) -> PNG, deterministic bytes."""
    path.parent.mkdir(parents=True, exist_ok=True)
    img = rgb[:, :, ::-1] if rgb.ndim == 3 else rgb
    if not cv2.imwrite(str(path), np.ascontiguousarray(img)):
        raise OSError(f"{path}: cannot write PNG")


def write_points_ply(path: Path, points: np.ndarray, colors: np.ndarray) -> None:
    """Binary PLY of points [N, 3] (float32 x, y, z) with uint8 red, green, blue."""
    from plyfile import PlyData, PlyElement

    path.parent.mkdir(parents=True, exist_ok=True)
    v = np.empty(len(points), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"),
                                     ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    v["x"], v["y"], v["z"] = points[:, 0], points[:, 1], points[:, 2]
    rgb = np.clip(np.round(colors * 255.0), 0, 255).astype(np.uint8)
    v["red"], v["green"], v["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    PlyData([PlyElement.describe(v, "vertex")]).write(str(path))


def downscale(rgb: np.ndarray, factor: int) -> np.ndarray:
    """Area-average downscale by an integer factor (how the publishers made rgb/2x, 4x)."""
    h, w = rgb.shape[:2]
    return cv2.resize(rgb, (w // factor, h // factor), interpolation=cv2.INTER_AREA)


class VideoWriter:
    """mp4v video of RGB frames."""

    def __init__(self, path: Path, width: int, height: int):
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), VIDEO_FPS, (width, height))
        if not self._w.isOpened():
            raise OSError(f"{path}: OpenCV cannot open an mp4v video writer")

    def write(self, rgb: np.ndarray) -> None:
        self._w.write(np.ascontiguousarray(rgb[:, :, ::-1]))

    def close(self) -> None:
        self._w.release()


# -- nerfies ------------------------------------------------------------------------------
def nerfies_raw_position(world_pos: np.ndarray) -> np.ndarray:
    return np.asarray(world_pos) / NERFIES_SCALE + NERFIES_CENTER


def nerfies_camera_json(cam: Camera) -> dict:
    """The nerfies camera file of a native camera whose pose is in the generator's world."""
    return {
        "orientation": cam.w2c[:3, :3].tolist(),
        "position": nerfies_raw_position(cam.center).tolist(),
        "focal_length": cam.fx,
        "principal_point": [cam.cx, cam.cy],
        "skew": float(cam.K[0, 1]),
        "pixel_aspect_ratio": cam.fy / cam.fx,
        "radial_distortion": list(cam.radial),
        "tangential_distortion": list(cam.tangential),
        "image_size": [cam.width, cam.height],
    }


def write_nerfies_meta(out: Path, items: list[tuple[str, int, int]], train_ids: list[str],
                       val_ids: list[str], points_world: np.ndarray, near: float, far: float) -> None:
    """dataset.json, metadata.json, scene.json, points.npy. items: (id, time_id, camera_id)."""
    ids = [i for i, _, _ in items]
    write_json(out / "dataset.json", {
        "count": len(ids), "num_exemplars": len(train_ids),
        "ids": ids, "train_ids": train_ids, "val_ids": val_ids,
    })
    write_json(out / "metadata.json", {
        i: {"time_id": t, "warp_id": t, "appearance_id": t, "camera_id": c} for i, t, c in items
    })
    write_json(out / "scene.json", {
        "scale": NERFIES_SCALE, "center": NERFIES_CENTER.tolist(),
        "near": near * NERFIES_SCALE, "far": far * NERFIES_SCALE,
    })
    np.save(out / "points.npy", nerfies_raw_position(points_world).astype(np.float64))


def write_nerfies_image(out: Path, item: str, rgb1x: np.ndarray, cam: Camera) -> None:
    write_json(out / "camera" / f"{item}.json", nerfies_camera_json(cam))
    write_png(out / "rgb" / "1x" / f"{item}.png", rgb1x)
    write_png(out / "rgb" / "2x" / f"{item}.png", downscale(rgb1x, 2))
    write_png(out / "rgb" / "4x" / f"{item}.png", downscale(rgb1x, 4))


# -- neu3d --------------------------------------------------------------------------------
def llff_row(cam: Camera, near: float, far: float) -> np.ndarray:
    """[17] poses_bounds row: c2w in LLFF axes [down, right, back] + [H, W, focal], near, far."""
    c2w = cam.c2w
    x, y, z, pos = c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3]
    m = np.stack([y, x, -z, pos, np.array([cam.height, cam.width, cam.fx])], axis=1)  # [3, 5]
    return np.concatenate([m.ravel(), [near, far]])


def write_poses_bounds(out: Path, cams: list[Camera], bounds: list[tuple[float, float]]) -> None:
    """Rows in the sorted order of the camera (= video) names."""
    order = sorted(range(len(cams)), key=lambda k: cams[k].name)
    rows = [llff_row(cams[k], *bounds[k]) for k in order]
    out.mkdir(parents=True, exist_ok=True)
    np.save(out / "poses_bounds.npy", np.stack(rows).astype(np.float64))


# -- immersive ----------------------------------------------------------------------------
def immersive_model(cam: Camera) -> dict:
    rvec, _ = cv2.Rodrigues(cam.w2c[:3, :3])
    return {
        "name": cam.name,
        "position": cam.center.tolist(),
        "orientation": rvec.ravel().tolist(),
        "focal_length": cam.fx,
        "pixel_aspect_ratio": cam.fy / cam.fx,
        "principal_point": [cam.cx, cam.cy],
        "width": float(cam.width),
        "height": float(cam.height),
        "radial_distortion": [cam.radial[0], cam.radial[1], 0.0],
        "projection_type": "fisheye",
    }


def write_models_json(out: Path, cams: list[Camera]) -> None:
    write_json(out / "models.json", [immersive_model(c) for c in cams])


# -- technicolor --------------------------------------------------------------------------
def technicolor_row(cam: Camera) -> str:
    from .gaussians import rotmat_to_quat

    q = rotmat_to_quat(cam.w2c[None, :3, :3])[0]
    t = cam.w2c[:3, 3]
    vals = [cam.fx, cam.cx, cam.cy, cam.fy / cam.fx, float(cam.K[0, 1]), *q, *t]
    return " ".join(repr(float(v)) for v in vals)


def write_technicolor_params(out: Path, cams: list[Camera]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    lines = ["f cu cv ar sk qw qx qy qz tx ty tz"] + [technicolor_row(c) for c in cams]
    (out / "cameras_parameters.txt").write_text("\n".join(lines) + "\n")


def technicolor_image_name(frame: int, cam_index: int) -> str:
    return f"{TECHNICOLOR_SCENE}_undist_{frame:05d}_{cam_index:02d}.png"
