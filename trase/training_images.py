"""The reconstruction's training images: read once (imagefiles' rule) at their camera's size."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from imagefiles import ImageFileError
from trase.camera import Camera


class ImageLoadError(ImageFileError):
    """A training image that cannot be used (missing, or not its camera's size); the message
    names the file and the problem. Undecodable files raise imagefiles' ImageFileError."""


def load_image(path: Path, camera: Camera, background: np.ndarray) -> np.ndarray:
    """[H, W, 3] float32 RGB in [0, 1] at the camera's size (resized with INTER_AREA when the
    file is larger by the downscale factor); 16-bit, gray and RGBA files by imagefiles' rule
    (alpha composited over ``background``)."""
    import cv2

    from imagefiles import read_rgb

    path = Path(path)
    if not path.is_file():
        raise ImageLoadError(f"{path}: training image not found")
    img = read_rgb(path, background)
    h, w = img.shape[:2]
    if (w, h) != (camera.width, camera.height):
        sx, sy = w / camera.width, h / camera.height
        if abs(sx - sy) > 0.02 * max(sx, sy) or sx < 1:
            raise ImageLoadError(
                f"{path}: image is {w}x{h} but its camera is {camera.width}x{camera.height}"
            )
        img = cv2.resize(img, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    return np.clip(img, 0.0, 1.0)


class ImageCache:
    """Images loaded once, as torch tensors [H, W, 3] on ``device``."""

    def __init__(self, views: Sequence, downscale: float, background: np.ndarray,
                 device: torch.device | str = "cpu") -> None:
        self.cameras: list[Camera] = []
        self.images: list[torch.Tensor] = []
        for v in views:
            cam = v.camera if downscale == 1 else v.camera.scaled(downscale)
            if not cam.is_pinhole:
                raise ImageLoadError(f"{v.image_path}: reconstruction needs undistorted pinhole cameras")
            self.cameras.append(cam)
            self.images.append(torch.from_numpy(load_image(Path(v.image_path), cam, background)).to(device))

    def __len__(self) -> int:
        return len(self.cameras)
