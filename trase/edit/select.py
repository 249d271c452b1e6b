"""Selections: bool [N] masks over a model's gaussians, from clusters, a click or a 2D mask.

Clicks and mask prompts use the method's own rules (``trase.prompts``), so what an editor
selects is what the benchmark's prompts would choose. ``keep`` (the similarity filter's
mask) applies when ``filtered`` is set, as in the paper's rendered objects.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from trase.camera import Camera
from trase.edit.model import EditableModel
from trase.prompts import DEFAULT_MASK_RULE, Click, click_to_cluster, mask_to_clusters
from trase.segment import select_gaussians


def by_clusters(model: EditableModel, clusters: Iterable[int], filtered: bool = True) -> np.ndarray:
    """[N] bool: gaussians of ``clusters`` (and passing the filter when ``filtered``)."""
    return select_gaussians(model.labels, clusters, model.keep if filtered else None)


def by_click(model: EditableModel, camera: Camera, u: float, v: float, rule: str = "depth",
             filtered: bool = True, exclude=()) -> tuple[int, np.ndarray]:
    """(cluster, [N] bool) under pixel (u, v) of ``camera`` (pixel centres at c + 0.5), never
    one of ``exclude`` (clusters negative clicks ruled out: the rule picks its best among the
    others); cluster -1 and an empty selection where the click hits no surface."""
    k = click_to_cluster(model.gaussians, model.deformation, camera, Click(u, v), model.labels, rule=rule,
                         exclude=tuple(exclude))
    return k, by_clusters(model, [k] if k >= 0 else [], filtered)


def by_mask(model: EditableModel, camera: Camera, mask: np.ndarray, rule: str = DEFAULT_MASK_RULE,
            filtered: bool = True) -> tuple[list[int], np.ndarray]:
    """(clusters, [N] bool) covered by the 2D ``mask`` [H, W] of ``camera`` (``rule``: see
    ``trase.prompts.mask_to_clusters``)."""
    ks = mask_to_clusters(model.gaussians, model.deformation, camera, mask, model.labels, rule=rule)
    return ks, by_clusters(model, ks, filtered)
