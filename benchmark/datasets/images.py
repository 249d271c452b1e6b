"""Small image helpers the loaders share: header-only size reads, reading and writing."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmark.datasets.errors import fail


def image_size(path: Path | str) -> tuple[int, int]:
    """(W, H) of an image file, reading only its header."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise fail(path, "image file does not exist")
    try:
        with Image.open(path) as im:
            return int(im.size[0]), int(im.size[1])
    except (UnidentifiedImageError, OSError) as exc:
        raise fail(path, f"cannot read image ({exc.__class__.__name__})") from None


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG")


def find_image(folder: Path, stem_or_name: str) -> Path:
    """``folder/name`` as given, else with one of the image suffixes; an error naming the
    expected ``.png`` when none exists."""
    p = Path(folder) / stem_or_name
    if p.is_file():
        return p
    for ext in IMAGE_SUFFIXES:
        q = Path(folder) / f"{stem_or_name}{ext}"
        if q.is_file():
            return q
    raise fail(p if p.suffix in IMAGE_SUFFIXES else Path(folder) / f"{stem_or_name}.png", "missing image")


def check_size(path: Path | str, width: int, height: int, what: str) -> None:
    """An image must be exactly the size its camera says."""
    w, h = image_size(path)
    if (w, h) != (width, height):
        raise fail(path, f"image is {w}x{h} but {what} says {width}x{height}")


def read_image(path: Path | str) -> np.ndarray:
    """[H, W, 3] uint8 BGR (OpenCV order, for ``write_image``) of imagefiles' picture, with the
    dataset error naming the file if unreadable."""
    from imagefiles import ImageFileError, read_rgb8

    try:
        return np.ascontiguousarray(read_rgb8(path)[:, :, ::-1])
    except ImageFileError as exc:
        raise fail(path, str(exc).removeprefix(f"{path}: ")) from None


def write_image(path: Path | str, img: np.ndarray) -> None:
    """Write atomically (temp file + rename) so an interrupted prepare leaves no half file."""
    import os

    import cv2

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    if not cv2.imwrite(str(tmp), img):
        raise fail(path, "cannot write image")
    os.replace(tmp, path)
