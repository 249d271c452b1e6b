"""How much new content each frame of a monocular sequence carries: the part of a frame its
time-neighbours do not already show.

    novelty = frame_novelty(images)   # images [T, H, W, 3] in time order -> [T]

A frame's novelty is the smaller of its mean absolute differences to the frame before and the
frame after (on copies at most ``side`` pixels on their longer side, so noise and sub-pixel
shifts count little): a frame that repeats either neighbour adds nothing the other frame does
not show. The first and last frames have one neighbour. Images are floats in [0, 1]. Measured
to decide whether a reconstruction could sample redundant frames less often (DashGaussian-style
skipping along time).
"""

from __future__ import annotations

import numpy as np

SIDE = 64  # the longer side frames are compared at


def _small(image: np.ndarray, side: int) -> np.ndarray:
    import cv2

    img = np.nan_to_num(np.asarray(image, dtype=np.float32))
    h, w = img.shape[:2]
    scale = min(1.0, side / max(h, w))
    if scale < 1.0:
        img = cv2.resize(img, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)
    return img


def frame_novelty(images, side: int = SIDE) -> np.ndarray:
    """[T] novelty of each frame of ``images`` ([T, H, W, C] or a list of [H, W, C], time order)."""
    small = [_small(im, side) for im in images]
    T = len(small)
    if T < 2:
        return np.zeros(T, np.float64)
    shapes = {s.shape for s in small}
    if len(shapes) != 1:
        raise ValueError(f"frame_novelty: frames of one sequence differ in size: {sorted(shapes)}")
    steps = np.array([float(np.abs(small[t + 1] - small[t]).mean()) for t in range(T - 1)])  # [T-1]
    before = np.concatenate([[np.inf], steps])
    after = np.concatenate([steps, [np.inf]])
    return np.minimum(before, after)


def novelty_summary(novelty: np.ndarray) -> dict:
    """The median and the share of frames carrying less than a half and a quarter of it."""
    nov = np.asarray(novelty, dtype=np.float64)
    if nov.size == 0:
        return {"frames": 0, "median": 0.0, "below_half": 0.0, "below_quarter": 0.0}
    med = float(np.median(nov))
    return {"frames": int(nov.size), "median": med,
            "below_half": float(np.mean(nov < 0.5 * med)), "below_quarter": float(np.mean(nov < 0.25 * med)),
            "min_to_median": float(nov.min() / med) if med > 0 else 0.0}


__all__ = ["SIDE", "frame_novelty", "novelty_summary"]
