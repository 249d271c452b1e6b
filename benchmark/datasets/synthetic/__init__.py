"""Built-in synthetic dynamic scenes in the five benchmarks' raw formats (the embedded default).

Public API::

    generate(dataset, out_dir, seed=0, size="small", difficulty="standard") -> Path  # raw format + truth
    ensure_synthetic(dataset, size="small", seed=0, cache_dir=None, difficulty="standard") -> Path
    find_or_generate(dataset, sequence, data_root) -> (scene_dir, variant)
    synthetic_copy(root, dataset, sequence) -> Path | None  # a scene `synth` wrote under a data root
    build_world(seed) -> World; render(world, camera, t) -> (rgb, depth, ids)
    SIZES, DATASET_KEYS, GENERATOR_VERSION, SyntheticError

Modules: ``shapes`` (exact ray intersections), ``world`` (the scene, motion, textures, ray
casting), ``rays`` (pixel rays through distorted / fisheye lenses), ``rigs`` (camera rigs per
dataset), ``formats`` (raw writers), ``gaussians`` (geometry.npz), ``generate``, ``cache``.
"""

from .cache import default_cache_dir, ensure_synthetic, find_or_generate, synthetic_copy
from .generate import (
    GENERATOR_VERSION,
    SEQUENCE_NAMES,
    SyntheticError,
    generate,
    parse_sequence_name,
    sequence_name,
)
from .rigs import DATASET_KEYS, DIFFICULTIES, SIZE_NAMES, SIZES
from .world import World, build_world, render

__all__ = [
    "DATASET_KEYS",
    "DIFFICULTIES",
    "GENERATOR_VERSION",
    "SEQUENCE_NAMES",
    "SIZES",
    "SIZE_NAMES",
    "SyntheticError",
    "World",
    "build_world",
    "default_cache_dir",
    "ensure_synthetic",
    "find_or_generate",
    "generate",
    "parse_sequence_name",
    "render",
    "sequence_name",
    "synthetic_copy",
]
