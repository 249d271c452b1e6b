"""TRASE's per-dataset settings (the paper's Sec. 4 and its public code's configs), owned by
the method: the datasets describe data, the method says how it treats each benchmark.

Np (pixels sampled per image) and M' (masks sampled per image) follow the camera rig:
monocular benchmarks 5000 / 25, multi-view 10000 / 50. The similarity filter's cosine
threshold is the paper's per benchmark. A capture of one's own (``trase-bench fit``) takes the
rig's Np / M' and 0.9, the threshold of two of the five benchmarks (HyperNeRF, Technicolor)
and their median; the cpu preset replaces every threshold by one value anyway
(``trase_method.CPU_FILTER_THRESHOLD``).
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class DatasetSettings:
    n_pixels: int  # Np: pixels sampled per image in feature learning
    n_masks: int  # M': masks sampled per image
    filter_threshold: float  # cosine threshold of the cluster filter (paper preset)


_MONO, _MULTI = {"n_pixels": 5000, "n_masks": 25}, {"n_pixels": 10000, "n_masks": 50}

PAPER_SETTINGS: dict[str, DatasetSettings] = {
    "nerfds": DatasetSettings(**_MONO, filter_threshold=0.4),
    "hypernerf": DatasetSettings(**_MONO, filter_threshold=0.9),
    "neu3d": DatasetSettings(**_MULTI, filter_threshold=0.98),
    "immersive": DatasetSettings(**_MULTI, filter_threshold=0.6),
    "technicolor": DatasetSettings(**_MULTI, filter_threshold=0.9),
}

OWN_CAPTURE_THRESHOLD = 0.9


def dataset_settings(dataset: str | None, monocular: bool = True) -> DatasetSettings:
    """The settings of benchmark ``dataset``; ``None`` (or a name the paper has no settings
    for): a capture of one's own, by its rig."""
    if dataset in PAPER_SETTINGS:
        return PAPER_SETTINGS[dataset]
    return DatasetSettings(**(_MONO if monocular else _MULTI), filter_threshold=OWN_CAPTURE_THRESHOLD)


__all__ = ["OWN_CAPTURE_THRESHOLD", "PAPER_SETTINGS", "DatasetSettings", "dataset_settings"]
