"""Neu3D (DyNeRF): ``camNN.mp4`` + ``poses_bounds.npy``.

``poses_bounds.npy`` is [N, 17]: per camera a 3x5 matrix (row-major) whose first four columns
are the camera-to-world pose in LLFF axes [down, right, back] and whose fifth column is
[H, W, focal], then near and far bounds. Row i belongs to the i-th video in sorted order; the
loader checks that the counts agree and that each video's frame size equals its row's [W, H].
No principal point is stored: it is the image centre (as in LLFF and the public code).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmark.datasets.errors import fail
from benchmark.datasets.video import read_frames, video_info
from trase.camera import Camera, CameraError


def list_videos(scene_dir: Path) -> list[Path]:
    videos = sorted(scene_dir.glob("cam*.mp4"))
    if not videos:
        raise fail(scene_dir, "no camNN.mp4 videos")
    return videos


def read_poses_bounds(path: Path | str, names: list[str] | None = None) -> tuple[list[Camera], np.ndarray]:
    """``poses_bounds.npy`` -> (native pinhole cameras in OpenCV axes, bounds [N, 2])."""
    path = Path(path)
    if not path.is_file():
        raise fail(path, "missing poses_bounds.npy")
    try:
        pb = np.load(path)
    except (ValueError, OSError) as exc:
        raise fail(path, f"cannot read ({exc.__class__.__name__})") from None
    if pb.ndim != 2 or pb.shape[1] != 17:
        raise fail(path, f"expected shape [N, 17], got {list(pb.shape)}")
    pb = pb.astype(np.float64)
    if names is not None and len(names) != len(pb):
        raise fail(path, f"{len(pb)} poses for {len(names)} videos (camNN.mp4)")
    cams = []
    for i, row in enumerate(pb):
        if not np.isfinite(row).all():
            raise fail(path, f"row {i} contains NaN or Inf")
        m = row[:15].reshape(3, 5)
        H, W, f = m[:, 4]
        down, right, back, t = m[:, 0], m[:, 1], m[:, 2], m[:, 3]
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, -back, t
        R = c2w[:3, :3].T
        w2c = np.eye(4)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ t
        if W <= 0 or H <= 0 or W != int(W) or H != int(H):
            raise fail(path, f"row {i}: image size {W}x{H} is not two positive integers")
        name = names[i] if names else f"cam{i:02d}"
        K = np.array([[f, 0.0, W / 2.0], [0.0, f, H / 2.0], [0.0, 0.0, 1.0]])
        try:
            cams.append(Camera(K=K, w2c=w2c, width=int(W), height=int(H), name=name))
        except CameraError as exc:
            raise fail(path, f"row {i}: {exc}") from None
    return cams, pb[:, 15:17]


class Neu3DSource:
    """Raw Neu3D sequence: native cameras and frames decoded from the videos."""

    def __init__(self, scene_dir: Path):
        self.dir = scene_dir
        self.videos = list_videos(scene_dir)
        names = [v.stem for v in self.videos]
        pb_path = scene_dir / "poses_bounds.npy"
        self.cameras, self.bounds = read_poses_bounds(pb_path, names)
        for cam, video in zip(self.cameras, self.videos):
            w, h, _ = video_info(video)
            if (w, h) != (cam.width, cam.height):
                raise fail(video, f"video is {w}x{h} but its poses_bounds.npy row says {cam.width}x{cam.height}")

    def frames(self, camera: str, frames: list[int]):
        return read_frames(self.dir / f"{camera}.mp4", frames)

    def depth_range(self) -> tuple[float, float]:
        return float(self.bounds[:, 0].min()), float(self.bounds[:, 1].max())
