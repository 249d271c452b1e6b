"""Which masks and which pixels one feature-training step looks at.

Rules (``sample_masks(maskset, rule, n, rng)`` returns sorted indices of the kept masks):

``random``  the paper's rule (its ``get_sample_pixel_and_mask``): every mask is kept
            independently with probability ``n / N``; ``n >= N`` keeps all. The count varies
            from step to step; its expectation is ``n``. (The paper: n = M' = 25 monocular,
            50 multi-view.)
``area``    the ``round(n)`` largest masks by pixel count. Equal areas are ordered by a
            random permutation from ``rng``, so ties do not always favour low indices.
``score``   the ``round(n)`` masks with the highest score (SAM: stability score). Ties as
            for ``area``. A MaskSet without scores is an error.
``grid``    "spatially uniform" (the paper's ablation): the image is split into ``round(n)``
            cells (the paper: 50) in an ``r x c`` grid with ``r * c == round(n)`` whose cells
            are closest to square for this image (50 cells on a landscape 4:3 image: 5 rows x
            10 columns). Each mask belongs to the one cell holding its centroid (mean pixel
            centre, (col + 0.5, row + 0.5)); each cell keeps its largest mask (ties: lowest
            index). Cells with no mask keep nothing, so at most ``round(n)`` masks come back;
            every mask is a candidate of exactly one cell, so none is picked twice. ``rng`` is
            not used.

``sample_pixels(valid, n_pixels, rng)``: each pixel kept with probability
``n_pixels / (H*W)``, then pixels outside ``valid`` (in the paper: covered by no mask) are
dropped; returns linear (row-major) indices.
"""

from __future__ import annotations

import numpy as np

from masks.maskset import MaskError, MaskSet

RULES = ("random", "area", "score", "grid")


def _count(n: float, total: int) -> int:
    return int(min(max(round(float(n)), 0), total))


def _top_k(values: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of the k largest values; ties broken by a random permutation."""
    perm = rng.permutation(values.shape[0])
    order = perm[np.argsort(-values[perm], kind="stable")]
    return np.sort(order[:k])


def grid_shape(n_cells: int, height: int, width: int) -> tuple[int, int]:
    """(rows, cols) with rows * cols == n_cells and cells closest to square."""
    if n_cells < 1:
        raise MaskError(f"grid needs at least one cell, got {n_cells}")
    best, best_cost = (1, n_cells), np.inf
    for rows in range(1, n_cells + 1):
        if n_cells % rows:
            continue
        cols = n_cells // rows
        cost = abs(np.log((width / cols) / (height / rows)))  # |log aspect| of one cell
        if cost < best_cost - 1e-12:
            best, best_cost = (rows, cols), cost
    return best


def mask_centroids(masks: np.ndarray) -> np.ndarray:
    """[N, 2] (x, y) mean pixel centre of each mask; NaN for an empty mask."""
    n, h, w = masks.shape
    area = masks.reshape(n, h * w).sum(1).astype(np.float64)
    rows = masks.sum(axis=2, dtype=np.float64)  # [N, H] pixels per row
    cols = masks.sum(axis=1, dtype=np.float64)  # [N, W]
    with np.errstate(invalid="ignore", divide="ignore"):
        cy = rows @ (np.arange(h) + 0.5) / area
        cx = cols @ (np.arange(w) + 0.5) / area
    return np.stack([cx, cy], axis=1)


def sample_grid(maskset: MaskSet, n_cells: int) -> np.ndarray:
    h, w = maskset.height, maskset.width
    if maskset.n == 0:
        return np.zeros(0, np.int64)
    rows, cols = grid_shape(n_cells, h, w)
    c = mask_centroids(maskset.masks)
    ok = np.isfinite(c).all(axis=1)
    cell_r = np.clip(np.floor(c[:, 1] / h * rows), 0, rows - 1)
    cell_c = np.clip(np.floor(c[:, 0] / w * cols), 0, cols - 1)
    cell = np.where(ok, cell_r * cols + cell_c, -1).astype(np.int64)
    best: dict[int, int] = {}
    for i in range(maskset.n):  # ascending index: strict > keeps the lowest index on ties
        k = int(cell[i])
        if k < 0:
            continue
        if k not in best or maskset.area[i] > maskset.area[best[k]]:
            best[k] = i
    return np.array(sorted(best.values()), np.int64)


def sample_masks(maskset: MaskSet, rule: str, n: float, rng: np.random.Generator) -> np.ndarray:
    """[K] int64 sorted indices of the masks kept by ``rule`` (see the module docstring)."""
    if n < 0 or not np.isfinite(n):
        raise MaskError(f"number of masks to sample must be a finite number >= 0, got {n}")
    total = maskset.n
    if rule == "random":
        if total == 0:
            return np.zeros(0, np.int64)
        keep = rng.random(total) < float(n) / total
        return np.flatnonzero(keep).astype(np.int64)
    if rule == "area":
        return _top_k(maskset.area.astype(np.float64), _count(n, total), rng).astype(np.int64)
    if rule == "score":
        if maskset.score is None:
            raise MaskError(f"rule 'score' needs mask scores; generator {maskset.generator!r} gave none")
        return _top_k(maskset.score.astype(np.float64), _count(n, total), rng).astype(np.int64)
    if rule == "grid":
        return sample_grid(maskset, round(float(n)))
    raise MaskError(f"unknown mask sampling rule {rule!r}; choose one of {', '.join(RULES)}")


def sample_pixels(valid: np.ndarray, n_pixels: float, rng: np.random.Generator) -> np.ndarray:
    """[P] int64 linear indices: each pixel kept with prob n_pixels/(H*W), then ``valid`` only."""
    valid = np.asarray(valid, dtype=bool)
    if valid.ndim != 2:
        raise MaskError(f"valid must be [H, W], got shape {valid.shape}")
    total = valid.size
    if total == 0:
        return np.zeros(0, np.int64)
    keep = rng.random(total) < float(n_pixels) / total
    return np.flatnonzero(keep & valid.reshape(-1)).astype(np.int64)
