"""Small deterministic MaskSets for the tests."""

from __future__ import annotations

import numpy as np

from masks import MaskSet


def blob_maskset(n: int = 7, h: int = 23, w: int = 31, seed: int = 0, score: bool = True) -> MaskSet:
    """Random overlapping ellipses; sizes chosen so N*H*W is not a multiple of 8."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    masks = np.zeros((n, h, w), bool)
    for i in range(n):
        cy, cx = rng.uniform(0, h), rng.uniform(0, w)
        ry, rx = rng.uniform(2, h / 2), rng.uniform(2, w / 2)
        masks[i] = ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 <= 1
    sc = rng.uniform(0.5, 1, n).astype(np.float32) if score else None
    return MaskSet.from_masks(masks, score=sc, generator="test", info={"seed": seed})


def shapes_image(h: int, w: int, seed: int = 0, n_objects: int = 8):
    """[H, W, 3] uint8 image of flat-ish coloured ellipses on a shaded background with pixel
    noise, and its [H, W] int32 ground-truth instance map (0 = background)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    img = np.zeros((h, w, 3), np.float64)
    img[:] = np.array([90, 110, 130]) + (yy / h * 40)[..., None]
    gt = np.zeros((h, w), np.int32)
    for i in range(1, n_objects + 1):
        cy, cx = rng.uniform(0.15, 0.85) * h, rng.uniform(0.15, 0.85) * w
        ry, rx = rng.uniform(0.06, 0.18) * h, rng.uniform(0.06, 0.18) * w
        m = ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 <= 1
        img[m] = rng.uniform(0, 255, 3) + (xx[m, None] - cx) / rx * 15  # colour + gradient
        gt[m] = i
    img += rng.normal(0, 6, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8), gt


def best_iou(masks: np.ndarray, target: np.ndarray) -> float:
    n = masks.shape[0]
    if n == 0:
        return 0.0
    flat = masks.reshape(n, -1)
    t = target.reshape(-1)
    inter = (flat & t).sum(1)
    union = (flat | t).sum(1)
    return float((inter / np.maximum(union, 1)).max())
