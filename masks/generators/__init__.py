"""Mask generators. All return a ``MaskSet`` from ``generate(image, key=..., instance_map=...)``.

``sam.SamGenerator``              segment-anything's automatic generator with the paper's settings
``classical.ClassicalGenerator``  OpenCV graph-based segmentation at several scales (+ SLIC)
``synthetic.SyntheticGenerator``  SAM-like noisy masks from an instance-id map (synthetic scenes)

Modules are imported on first use so OpenCV / segment-anything load only when needed.
Installed packages add generators through the entry-point group ``trase_bench.mask_generators``
(``name = module:GeneratorClass``; ``--set masks.generator=name``).
"""

from __future__ import annotations

from lazyspecs import Registry, describe
from masks.generators.base import MaskGenerator, min_area_for
from masks.maskset import MaskError


def check_generator_class(obj) -> str | None:
    """What keeps a plugin's object from being a mask generator (a phrase), or None."""
    if isinstance(obj, type) and callable(getattr(obj, "generate", None)) and callable(getattr(obj, "settings", None)):
        return None
    return f"{describe(obj)} is not a mask generator class (generate(image, key=, instance_map=) and settings())"


GENERATORS = Registry("mask generator", MaskError, group="trase_bench.mask_generators", check=check_generator_class)
GENERATORS.add("sam", "masks.generators.sam:SamGenerator", "segment-anything's automatic masks (local checkpoint)")
GENERATORS.add("classical", "masks.generators.classical:ClassicalGenerator", "OpenCV graph segmentation + SLIC")
GENERATORS.add("synthetic", "masks.generators.synthetic:SyntheticGenerator", "SAM-like masks from instance maps")


def make_generator(name: str, **kwargs) -> MaskGenerator:
    """Build a generator by name (``GENERATORS``), its module imported on first use."""
    return GENERATORS.load(name)(**kwargs)


__all__ = ["GENERATORS", "MaskGenerator", "check_generator_class", "make_generator", "min_area_for"]
