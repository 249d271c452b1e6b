"""What every generator offers, and the clean-up rules they share."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from masks.maskset import MaskError

# SAM's min_mask_region_area is 100 pixels on the images the paper fed it; HyperNeRF / NeRF-DS
# at 2x are about 536 x 960. Smaller images scale the threshold with their pixel count.
SAM_MIN_AREA = 100
REFERENCE_PIXELS = 536 * 960


def min_area_for(height: int, width: int, base: float = SAM_MIN_AREA) -> int:
    """SAM's 100-pixel minimum mask area, scaled to this image's pixel count (at least 1)."""
    return max(1, round(base * height * width / REFERENCE_PIXELS))


def drop_degenerate(masks: np.ndarray, min_area: int) -> np.ndarray:
    """[N] bool keep-flags: area >= min_area and not the whole image (the paper drops masks
    with a single value, i.e. empty or full)."""
    n, h, w = masks.shape
    area = masks.reshape(n, h * w).sum(axis=1)
    return (area >= max(1, min_area)) & (area < h * w)


@runtime_checkable
class MaskGenerator(Protocol):
    name: str  # stored in MaskSet.generator
    needs_instance_map: bool  # True for the synthetic generator

    def generate(self, image: np.ndarray | None, key: str = "",
                 instance_map: np.ndarray | None = None):  # -> MaskSet
        ...

    def settings(self) -> dict:  # JSON-serialisable, stored in MaskSet.info
        ...


def check_image(image: np.ndarray | None, who: str) -> np.ndarray:
    """[H, W, 3] uint8 RGB or a clear error."""
    if image is None:
        raise MaskError(f"{who} needs an image")
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise MaskError(f"{who}: image must be [H, W, 3], got shape {img.shape}")
    img = img[..., :3]
    if img.dtype != np.uint8:
        if np.issubdtype(img.dtype, np.floating) and np.nanmax(img, initial=0) <= 1.0:
            img = np.clip(np.nan_to_num(img) * 255.0 + 0.5, 0, 255)
        img = np.clip(img, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)
