"""The one structure every generator returns and every store reads and writes.

A ``MaskSet`` holds the "anything" masks of one image: N overlapping binary masks with no
identity across images. Areas are always known (they are recomputed from the masks when a file
does not carry them); a score is known only for generators that have one (SAM's stability
score, the classical generator's cross-scale stability, the synthetic generator's IoU with the
clean mask).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np


class MaskError(ValueError):
    """Bad mask input (file, array or argument); the CLI prints it as one line."""

    user_facing = True


@dataclasses.dataclass(eq=False)
class MaskSet:
    masks: np.ndarray  # [N, H, W] bool
    area: np.ndarray  # [N] int64, pixel count of each mask
    score: np.ndarray | None = None  # [N] float32, or None when the source has no score
    generator: str = "unknown"  # who made them: "sam", "classical", "synthetic", "official"...
    info: dict = dataclasses.field(default_factory=dict)  # JSON-serialisable facts (settings...)

    def __post_init__(self) -> None:
        m = np.asarray(self.masks)
        if m.ndim != 3:
            raise MaskError(f"masks must be [N, H, W], got shape {m.shape}")
        self.masks = m if m.dtype == np.bool_ else m.astype(bool)
        self.area = np.asarray(self.area, dtype=np.int64).reshape(-1)
        if self.area.shape[0] != self.masks.shape[0]:
            raise MaskError(f"{self.area.shape[0]} areas for {self.masks.shape[0]} masks")
        if self.score is not None:
            self.score = np.asarray(self.score, dtype=np.float32).reshape(-1)
            if self.score.shape[0] != self.masks.shape[0]:
                raise MaskError(f"{self.score.shape[0]} scores for {self.masks.shape[0]} masks")

    @classmethod
    def from_masks(
        cls,
        masks: np.ndarray,
        score: np.ndarray | None = None,
        generator: str = "unknown",
        info: dict | None = None,
    ) -> MaskSet:
        """Build from a [N, H, W] array, computing areas."""
        m = np.asarray(masks).astype(bool, copy=False)
        if m.ndim != 3:
            raise MaskError(f"masks must be [N, H, W], got shape {m.shape}")
        area = m.reshape(m.shape[0], m.shape[1] * m.shape[2]).sum(axis=1, dtype=np.int64)
        return cls(m, area, score, generator, dict(info or {}))

    @classmethod
    def empty(cls, height: int, width: int, generator: str = "unknown", info: dict | None = None):
        return cls(np.zeros((0, height, width), bool), np.zeros(0, np.int64), None, generator,
                   dict(info or {}))

    # ------------------------------------------------------------------ shape
    @property
    def n(self) -> int:
        return int(self.masks.shape[0])

    @property
    def height(self) -> int:
        return int(self.masks.shape[1])

    @property
    def width(self) -> int:
        return int(self.masks.shape[2])

    def __len__(self) -> int:
        return self.n

    # ------------------------------------------------------------ derived data
    @functools.cached_property
    def coverage(self) -> np.ndarray:
        """[H, W] int32: how many masks cover each pixel."""
        out = np.zeros((self.height, self.width), np.int32)
        for m in self.masks:
            out += m
        return out

    @property
    def covered(self) -> np.ndarray:
        """[H, W] bool: pixels inside at least one mask (the only pixels training samples)."""
        return self.coverage > 0

    @functools.cached_property
    def pixel_mean_area(self) -> np.ndarray:
        """[H, W] float32: mean area of all masks covering each pixel, 0 where none.

        TRASE's pixel weight s_i (DESIGN.md). Accumulated mask by mask so memory stays
        O(H*W) however many masks there are.
        """
        total = np.zeros((self.height, self.width), np.float64)
        for m, a in zip(self.masks, self.area):
            total[m] += float(a)
        cov = self.coverage
        out = np.zeros_like(total)
        np.divide(total, cov, out=out, where=cov > 0)
        return out.astype(np.float32)

    def subset(self, indices: np.ndarray) -> MaskSet:
        """The masks at ``indices`` (any integer index array or bool selector)."""
        idx = np.asarray(indices)
        return MaskSet(
            self.masks[idx],
            self.area[idx],
            None if self.score is None else self.score[idx],
            self.generator,
            dict(self.info),
        )

    def equals(self, other: MaskSet, check_score: bool = True) -> bool:
        """Bit-exact equality of masks (and areas, and scores when asked)."""
        if self.masks.shape != other.masks.shape:
            return False
        if not np.array_equal(self.masks, other.masks) or not np.array_equal(self.area, other.area):
            return False
        if check_score:
            if (self.score is None) != (other.score is None):
                return False
            if self.score is not None and not np.array_equal(self.score, other.score):
                return False
        return True
