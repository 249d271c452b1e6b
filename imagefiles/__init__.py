"""Pictures from image files: one reader, one rule, for every layer.

Why one: mask generation, reconstruction, reports and ``prepare`` all look at the same
training images. With a reader each, an RGBA or 16-bit capture gave them different pictures
(masks were cut from the raw RGB of an RGBA file while reconstruction trained on it composited
over its background; 16-bit files were rounded one way here and truncated another way there).

The rule:
* samples: 8-bit divided by 255, 16-bit by 65535; any other sample type is an error;
* a gray image becomes three equal channels;
* an alpha channel is straight alpha (PNG's definition): the picture is
  ``rgb * a + background * (1 - a)``, over black unless the caller names a background (the
  reconstruction's ``white_background`` setting decides it for a run);
* ``read_rgb8`` is ``round(255 * read_rgb)``, so an 8-bit RGB file comes back byte for byte.

Label images (instance maps, ground-truth masks) are not pictures and have readers of their own;
``read_mask`` reads a drawn or cut-out mask (a selection prompt): the alpha channel where the
file has one (alpha >= 0.5: an RGBA cut-out of the object, as D-NeRF's frames are), else every
pixel with a non-zero sample (0/255, 0/1 or coloured masks).
"""

from __future__ import annotations

import os

import numpy as np

BLACK = (0.0, 0.0, 0.0)
WHITE = (1.0, 1.0, 1.0)


class ImageFileError(ValueError):
    """An image file that is missing or cannot be read as a picture ("PATH: problem")."""

    user_facing = True


def _decode(path: os.PathLike | str) -> tuple[np.ndarray, np.ndarray | None, float]:
    """(rgb [H, W, 3] in the file's sample type, alpha [H, W] or None, the sample maximum)."""
    import cv2

    if not os.path.isfile(path):
        raise ImageFileError(f"{path}: image file not found")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ImageFileError(f"{path}: cannot decode image (not an image file, or truncated)")
    if img.dtype == np.uint8:
        top = 255.0
    elif img.dtype == np.uint16:
        top = 65535.0
    else:
        raise ImageFileError(f"{path}: unsupported sample type {img.dtype} (8- or 16-bit images only)")
    if img.ndim == 2:
        return np.repeat(img[:, :, None], 3, axis=2), None, top
    if img.shape[2] == 1:
        return np.repeat(img, 3, axis=2), None, top
    if img.shape[2] == 2:  # gray + alpha
        return np.repeat(img[:, :, :1], 3, axis=2), img[:, :, 1], top
    rgb = img[:, :, 2::-1]  # OpenCV's BGR(A) -> RGB
    alpha = img[:, :, 3] if img.shape[2] == 4 else None
    return rgb, alpha, top


def read_rgb(path: os.PathLike | str, background=None) -> np.ndarray:
    """[H, W, 3] float32 RGB in [0, 1] by the module's rule; ``background``: 3 floats in
    [0, 1] under transparent pixels (default black)."""
    return _picture(*_decode(path), background)


def _picture(rgb: np.ndarray, alpha: np.ndarray | None, top: float, background) -> np.ndarray:
    img = rgb.astype(np.float32) / np.float32(top)
    if alpha is not None:
        a = (alpha.astype(np.float32) / np.float32(top))[:, :, None]
        bg = np.asarray(BLACK if background is None else background, np.float32).reshape(1, 1, 3)
        img = img * a + bg * (1 - a)
    return np.ascontiguousarray(img)


def read_rgb8(path: os.PathLike | str, background=None) -> np.ndarray:
    """[H, W, 3] uint8 RGB: ``round(255 * read_rgb(path, background))``; an 8-bit RGB or gray
    file's own bytes."""
    rgb, alpha, top = _decode(path)
    if rgb.dtype == np.uint8 and alpha is None:
        return np.ascontiguousarray(rgb)
    return np.round(_picture(rgb, alpha, top, background) * 255.0).astype(np.uint8)


def read_mask(path: os.PathLike | str) -> np.ndarray:
    """[H, W] bool mask of an image file by the module docstring's rule."""
    rgb, alpha, top = _decode(path)
    if alpha is not None:
        return alpha.astype(np.float32) >= np.float32(0.5 * top)
    return rgb.any(axis=2)


def png_bytes(image: np.ndarray) -> bytes:
    """PNG file bytes of an RGB uint8 [H, W, 3] picture or a one-channel 8/16-bit map [H, W]."""
    import cv2

    img = np.ascontiguousarray(image[..., ::-1] if image.ndim == 3 else image)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ImageFileError(f"cannot encode a {image.dtype} {list(image.shape)} picture as PNG")
    return buf.tobytes()


__all__ = ["BLACK", "WHITE", "ImageFileError", "png_bytes", "read_mask", "read_rgb", "read_rgb8"]
