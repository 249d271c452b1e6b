"""The five *-Mask benchmarks: registry, loaders for the publishers' formats, preparation.

Public API::

    DATASETS, DatasetSpec, get_dataset, nerfies_time      # registry
    load_scene(dataset, scene_dir, sequence=None) -> Scene
    find_scene_dir(dataset, sequence, data_root) -> Path | None
    find_gt_dir(dataset, sequence, data_root=None, scene_dir=None) -> Path | None
    DatasetError                                           # every bad-input error
"""

from benchmark.datasets.errors import DatasetError
from benchmark.datasets.layout import align_gt, data_root, find_gt_dir, find_scene_dir
from benchmark.datasets.loader import load_scene
from benchmark.datasets.registry import DATASETS, DatasetSpec, get_dataset, nerfies_time
from benchmark.datasets.scene import Scene, View

__all__ = [
    "DATASETS",
    "DatasetError",
    "DatasetSpec",
    "Scene",
    "View",
    "align_gt",
    "data_root",
    "find_gt_dir",
    "find_scene_dir",
    "get_dataset",
    "load_scene",
    "nerfies_time",
]
