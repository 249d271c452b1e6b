"""Mask generators. All return a ``MaskSet`` from ``generate(image, key=..., instance_map=...)``.

``sam.SamGenerator``              segment-anything's automatic generator with the paper's settings
``classical.ClassicalGenerator``  OpenCV graph-based segmentation at several scales (+ SLIC)
``synthetic.SyntheticGenerator``  SAM-like noisy masks from an instance-id map (synthetic scenes)

Modules are imported on first use so OpenCV / segment-anything load only when needed.
"""

from __future__ import annotations

from masks.generators.base import MaskGenerator, make_generator, min_area_for

__all__ = ["MaskGenerator", "make_generator", "min_area_for"]
