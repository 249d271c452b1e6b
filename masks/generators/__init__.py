"""Mask generators. All return a ``MaskSet`` from ``generate(image, key=..., instance_map=...)``.

``sam.SamGenerator``              segment-anything's automatic generator with the paper's settings
``classical.ClassicalGenerator``  OpenCV graph-based segmentation at several scales (+ SLIC)
``synthetic.SyntheticGenerator``  SAM-like noisy masks from an instance-id map (synthetic scenes)

Modules are imported on first use so OpenCV / segment-anything load only when needed.
"""

from __future__ import annotations

from lazyspecs import Registry
from masks.generators.base import MaskGenerator, min_area_for
from masks.maskset import MaskError

GENERATORS = Registry("mask generator", MaskError)
GENERATORS.add("sam", "masks.generators.sam:SamGenerator", "segment-anything's automatic masks (local checkpoint)")
GENERATORS.add("classical", "masks.generators.classical:ClassicalGenerator", "OpenCV graph segmentation + SLIC")
GENERATORS.add("synthetic", "masks.generators.synthetic:SyntheticGenerator", "SAM-like masks from instance maps")


def make_generator(name: str, **kwargs) -> MaskGenerator:
    """Build a generator by name (``GENERATORS``), its module imported on first use."""
    return GENERATORS.load(name)(**kwargs)


__all__ = ["GENERATORS", "MaskGenerator", "make_generator", "min_area_for"]
