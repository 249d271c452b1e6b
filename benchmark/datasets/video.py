"""Frames out of the publishers' videos (Neu3D camNN.mp4, Immersive camera_XXXX.mp4), with OpenCV."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from benchmark.datasets.errors import fail


def video_info(path: Path) -> tuple[int, int, int]:
    """(W, H, frame count as the container reports it) of a video file."""
    import cv2

    if not path.is_file():
        raise fail(path, "missing video")
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise fail(path, "cannot open video")
        w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        cap.release()
    if w <= 0 or h <= 0:
        raise fail(path, "video reports no frame size")
    return w, h, n


def read_frames(path: Path, frames: list[int]) -> Iterator[tuple[int, np.ndarray]]:
    """Decode ``frames`` (0-based frame numbers, ascending) as [H, W, 3] uint8 BGR.

    Decodes sequentially from the first wanted frame (seeking in mp4 is not frame-exact with
    every codec); a video that ends early is an error naming the missing frame.
    """
    import cv2

    if not frames:
        return
    wanted = sorted(set(frames))
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise fail(path, "cannot open video")
    try:
        k = 0
        for target in wanted:
            while k <= target:
                ok, img = cap.read()
                if not ok:
                    raise fail(path, f"video ends at frame {k}, frame {target} is needed")
                k += 1
            yield target, img
    finally:
        cap.release()
