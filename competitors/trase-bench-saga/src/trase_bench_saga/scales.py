"""The 3D scale of a 2D mask, and the map from scales to the gate's input in [0, 1].

A mask's scale (SAGA, ``get_scale.py``): the mask is eroded (3x3 neighbourhood, at least 5 of
its 9 pixels inside), its pixels are lifted to 3D with the geometry's rendered depth, and the
scale is the norm of twice the per-axis standard deviation of those points. The norm of the
per-axis deviations is the square root of the covariance's trace, so camera or world axes give
the same value.

The gate does not see a scale itself but its quantile among all the masks' scales of the
training views (SAGA fits scikit-learn's ``QuantileTransformer`` with a uniform output);
``QuantileMap`` is that map as a piecewise-linear interpolation over the sample's quantiles.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import ndimage

ERODE_MIN = 5  # of the 3x3 pixels around a pixel, at least this many inside the mask
N_QUANTILES = 1000  # scikit-learn's QuantileTransformer default


def eroded(mask: np.ndarray, min_inside: int = ERODE_MIN) -> np.ndarray:
    """[H, W] bool -> [H, W] bool: pixels whose 3x3 neighbourhood (zero outside the image) has at
    least ``min_inside`` mask pixels."""
    count = ndimage.correlate(np.asarray(mask, np.int32), np.ones((3, 3), np.int32), mode="constant", cval=0)
    return count >= int(min_inside)


def mask_scale(points: np.ndarray, surface: np.ndarray, mask: np.ndarray, min_inside: int = ERODE_MIN) -> float:
    """points [H, W, 3] lifted pixels, surface [H, W] bool (pixels with a depth), mask [H, W] ->
    ||2 std(points in the eroded mask)||; the whole mask where erosion leaves fewer than 2 points,
    0.0 where the mask has fewer than 2 points with a depth."""
    for region in (eroded(mask, min_inside) & surface, np.asarray(mask, bool) & surface):
        pts = points[region]
        if len(pts) >= 2:
            return float(np.linalg.norm(2.0 * pts.std(axis=0, ddof=1)))
    return 0.0


def mask_scales(points: np.ndarray, surface: np.ndarray, masks: np.ndarray, min_inside: int = ERODE_MIN) -> np.ndarray:
    """[M] float64 scale of each of ``masks`` [M, H, W]."""
    return np.array([mask_scale(points, surface, m, min_inside) for m in masks], np.float64)


@dataclasses.dataclass
class QuantileMap:
    """scale -> its quantile in [0, 1] among the fitted scales (linear between quantiles)."""

    knots: np.ndarray  # [Q] ascending scale values at the quantiles linspace(0, 1, Q)

    @classmethod
    def fit(cls, scales: np.ndarray, n_quantiles: int = N_QUANTILES) -> QuantileMap:
        s = np.asarray(scales, np.float64).reshape(-1)
        if s.size == 0:
            return cls(np.zeros(1))
        q = max(1, min(int(n_quantiles), s.size))
        return cls(np.quantile(s, np.linspace(0.0, 1.0, q)))

    def __call__(self, scales) -> np.ndarray:
        s = np.asarray(scales, np.float64)
        if self.knots.size < 2 or self.knots[-1] <= self.knots[0]:
            return np.where(s > self.knots[-1], 1.0, 0.0) if self.knots.size else np.zeros_like(s)
        levels = np.linspace(0.0, 1.0, self.knots.size)
        # ties (several knots of one value): the mean of the rising and falling interpolations
        up = np.interp(s, self.knots, levels)
        down = -np.interp(-s, -self.knots[::-1], -levels[::-1])
        return 0.5 * (up + down)

    def to_list(self) -> list[float]:
        return [float(v) for v in self.knots]
