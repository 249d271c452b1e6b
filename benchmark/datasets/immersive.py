"""Google Immersive (DeepView video): ``camera_XXXX.mp4`` + ``models.json``.

``models.json`` is a list of cameras: ``name``, ``position`` (centre), ``orientation``
(axis-angle of the world-to-camera rotation), ``focal_length``, ``pixel_aspect_ratio``,
``principal_point``, ``width``/``height`` (floats), ``radial_distortion`` [k1, k2, 0] and
``projection_type`` "fisheye": equidistant, theta = atan2(r, z),
r_d = theta (1 + k1 theta^2 + k2 theta^4) (cv2.fisheye with D = [k1, k2, 0, 0]).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from benchmark.datasets.errors import fail
from benchmark.datasets.jsonio import field, finite_array, finite_float, read_json
from benchmark.datasets.video import read_frames, video_info
from trase.camera import Camera, CameraError


def read_models(path: Path | str) -> list[Camera]:
    """``models.json`` -> native fisheye cameras (OpenCV axes, native resolution)."""
    path = Path(path)
    models = read_json(path, "models.json")
    if not isinstance(models, list) or not models:
        raise fail(path, "expected a non-empty JSON list of cameras")
    cams = []
    for i, m in enumerate(models):
        where = f"camera {i}"
        name = str(field(m, "name", path, where))
        where = f"camera {name!r}"
        c = finite_array(field(m, "position", path, where), path, f"position of {name}", (3,))
        rv = finite_array(field(m, "orientation", path, where), path, f"orientation of {name}", (3,))
        f = finite_float(field(m, "focal_length", path, where), path, f"focal_length of {name}")
        aspect = finite_float(m.get("pixel_aspect_ratio", 1.0), path, f"pixel_aspect_ratio of {name}")
        pp = finite_array(field(m, "principal_point", path, where), path, f"principal_point of {name}", (2,))
        W = finite_float(field(m, "width", path, where), path, f"width of {name}")
        H = finite_float(field(m, "height", path, where), path, f"height of {name}")
        k = finite_array(m.get("radial_distortion", [0.0, 0.0, 0.0]), path, f"radial_distortion of {name}")
        proj = m.get("projection_type", "fisheye")
        if proj != "fisheye":
            raise fail(path, f"{where}: projection_type {proj!r} is not supported (expected 'fisheye')")
        if k.ndim != 1 or not 1 <= k.size <= 3:
            raise fail(path, f"{where}: radial_distortion must hold 1 to 3 values")
        k = np.concatenate([k, np.zeros(3 - k.size)])
        if W <= 0 or H <= 0 or W != int(W) or H != int(H):
            raise fail(path, f"{where}: image size {W}x{H} is not two positive integers")
        R = Rotation.from_rotvec(rv).as_matrix()
        w2c = np.eye(4)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ c
        K = np.array([[f, 0.0, pp[0]], [0.0, f * aspect, pp[1]], [0.0, 0.0, 1.0]])
        try:
            cams.append(Camera(K=K, w2c=w2c, width=int(W), height=int(H), name=name,
                               radial=tuple(k), fisheye=True))
        except CameraError as exc:
            raise fail(path, f"{where}: {exc}") from None
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        raise fail(path, "camera names are not unique")
    return cams


class ImmersiveSource:
    """Raw Immersive sequence: native fisheye cameras and frames decoded from the videos."""

    def __init__(self, scene_dir: Path):
        self.dir = scene_dir
        models_path = scene_dir / "models.json"
        self.cameras = read_models(models_path)
        videos = sorted(scene_dir.glob("*.mp4"))
        names = {c.name for c in self.cameras}
        stems = {v.stem for v in videos}
        if names != stems:
            missing = sorted(names - stems)
            extra = sorted(stems - names)
            raise fail(models_path, f"{len(names)} cameras for {len(videos)} videos"
                       + (f"; no video for {', '.join(missing[:3])}" if missing else "")
                       + (f"; no camera for {', '.join(e + '.mp4' for e in extra[:3])}" if extra else ""))
        for cam in self.cameras:
            video = scene_dir / f"{cam.name}.mp4"
            w, h, _ = video_info(video)
            if (w, h) != (cam.width, cam.height):
                raise fail(video, f"video is {w}x{h} but models.json says {cam.width}x{cam.height}")

    def frames(self, camera: str, frames: list[int]):
        return read_frames(self.dir / f"{camera}.mp4", frames)

    def depth_range(self) -> None:
        return None
