"""Captures at any scale: the images of a capture scaled on the fly, for layouts (or users)
that ship no pre-scaled copy.

``capture.image_scale=N`` asks for images at 1/N of the cameras' size. A layout that has the
copy (nerfies ``rgb/<N>x``, COLMAP ``images_<N>``, transforms ``<folder>_<N>``) uses it as
it is; where it has none, the layout reads the finest copy it has and this module scales the
views the rest of the way. ``capture.max_side`` then scales whatever came out so its longest
side is at most that many pixels. The scaled files are written once into a cache folder keyed
by the source file's content and the target size, so the stages' cache keys, which fingerprint
the image files, stay the same from one run to the next.

How: area filter (OpenCV's INTER_AREA), in premultiplied alpha where the source has an alpha
channel, so that compositing the scaled file over any background gives the scaled composite
(straight alpha resized as it is would bleed the colour of transparent pixels into the edges);
the result is a 16-bit PNG (RGB, or RGBA with the alpha kept), so no precision is lost to
rounding before the reconstruction reads it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from pathlib import Path

import numpy as np

from benchmark.datasets.errors import fail
from benchmark.datasets.scene import View

SCALED_VERSION = 1  # part of every cached file's key: a change of the method re-scales


def cache_root() -> Path:
    """Where scaled copies go: $TRASE_BENCH_CACHE/scaled, else ~/.cache/trase-bench/scaled."""
    import cachedir

    return cachedir.subfolder("scaled")


def target_size(width: int, height: int, factor: float) -> tuple[int, int]:
    """(W, H) of an image of ``width`` x ``height`` scaled down by ``factor`` (>= 1), at least 1 px."""
    return max(1, round(width / factor)), max(1, round(height / factor))


def scaled_file(source: Path, size: tuple[int, int], root: Path | None = None) -> Path:
    """``source`` scaled to ``size`` (W, H), written once under ``root`` and reused after (the
    key is the source's content: reading it costs far less than decoding and resizing)."""
    source = Path(source)
    try:
        content = hashlib.sha1(source.read_bytes()).hexdigest()
    except OSError as exc:
        raise fail(source, f"cannot read image ({exc.__class__.__name__})") from None
    key = hashlib.sha1(f"{content}|{size[0]}x{size[1]}|{SCALED_VERSION}".encode()).hexdigest()
    out = (root or cache_root()) / key[:2] / f"{key}.png"
    if out.is_file():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    img = _area_scaled(source, size)
    import cv2

    tmp = out.with_name(f".{out.stem}.{os.getpid()}.tmp.png")
    try:
        if not cv2.imwrite(str(tmp), img):
            raise fail(out, "cannot write the scaled image")
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return out


def _area_scaled(source: Path, size: tuple[int, int]) -> np.ndarray:
    """[H, W, C] uint16 BGR(A) of ``source`` resized to ``size`` by area, in premultiplied alpha."""
    import cv2

    img = cv2.imread(str(source), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise fail(source, "cannot decode image (not an image file, or truncated)")
    if img.dtype not in (np.uint8, np.uint16):
        raise fail(source, f"unsupported sample type {img.dtype} (8- or 16-bit images only)")
    top = 255.0 if img.dtype == np.uint8 else 65535.0
    x = img.astype(np.float64) / top
    if x.ndim == 2:
        x = x[:, :, None]
    if x.shape[2] == 2:  # gray + alpha -> BGRA
        x = np.concatenate([np.repeat(x[:, :, :1], 3, axis=2), x[:, :, 1:]], axis=2)
    elif x.shape[2] == 1:
        x = np.repeat(x, 3, axis=2)
    if x.shape[2] == 4:
        a = x[:, :, 3:]
        pre = np.concatenate([x[:, :, :3] * a, a], axis=2)
        small = cv2.resize(pre, size, interpolation=cv2.INTER_AREA)
        alpha = small[:, :, 3:]
        rgb = np.divide(small[:, :, :3], alpha, out=np.zeros_like(small[:, :, :3]), where=alpha > 1e-12)
        out = np.concatenate([np.clip(rgb, 0.0, 1.0), np.clip(alpha, 0.0, 1.0)], axis=2)
    else:
        out = np.clip(cv2.resize(x, size, interpolation=cv2.INTER_AREA), 0.0, 1.0)
    return np.round(out * 65535.0).astype(np.uint16)


def scaled_view(view: View, factor: float, root: Path | None = None) -> View:
    """``view`` with its image scaled down by ``factor`` (>= 1) and its camera to match: the
    intrinsics scale per axis by the sizes' exact ratio (a size that does not divide rounds)."""
    cam = view.camera
    w, h = target_size(cam.width, cam.height, factor)
    K = cam.K.copy()
    K[0] *= w / cam.width
    K[1] *= h / cam.height
    small = dataclasses.replace(cam, K=K, width=w, height=h)
    return dataclasses.replace(view, camera=small, image_path=scaled_file(view.image_path, (w, h), root))


def rescale(views: list[View], factor: float, root: Path | None = None) -> list[View]:
    """Every view scaled down by ``factor`` (1: as they are)."""
    if factor <= 1.0:
        return list(views)
    return [scaled_view(v, factor, root) for v in views]


def max_side_factor(views: list[View], max_side: int) -> float:
    """The factor bringing the longest side of any view to at most ``max_side`` (1 if none is longer)."""
    if max_side <= 0 or not views:
        return 1.0
    longest = max(max(v.camera.width, v.camera.height) for v in views)
    return max(1.0, longest / max_side)


__all__ = ["cache_root", "max_side_factor", "rescale", "scaled_file", "scaled_view", "target_size"]
