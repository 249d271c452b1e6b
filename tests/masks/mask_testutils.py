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
