"""The paper's feature-space statistics (supplementary, "Soft vs. Hard vs. All Mining" table):
mean intra-cluster and inter-cluster distances of the learned features.

The paper does not spell out the formula; its values (inter ~1.38, close to sqrt(2) for
orthogonal unit vectors, and never above 2) show Euclidean distances between L2-normalised
features. Our definition, computed for any trained model and any labelling:

* intra = mean over gaussians of || f_i / |f_i| - c_(label i) ||, where c_k is the
  L2-normalised mean of cluster k's normalised features (every gaussian counts once);
* inter = mean over unordered pairs of distinct clusters (k < l) of || c_k - c_l ||
  (every cluster pair counts once, whatever the cluster sizes).

inter is NaN when there are fewer than two clusters (undefined, not zero).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from trase.clustering import _centres, normalise


@dataclasses.dataclass(frozen=True)
class FeatureStats:
    intra: float  # mean distance of a gaussian's unit feature to its cluster centre (lower: tighter)
    inter: float  # mean distance between cluster centres (higher: better separated)
    n_clusters: int
    n_gaussians: int

    def to_dict(self) -> dict:
        clean = lambda x: None if math.isnan(x) else float(x)
        return {"intra": clean(self.intra), "inter": clean(self.inter),
                "n_clusters": self.n_clusters, "n_gaussians": self.n_gaussians}


def feature_space_stats(features, labels) -> FeatureStats:
    """features [N, D], labels [N] int (any values; -1 is just another label) -> FeatureStats."""
    fn = normalise(features)
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    if labels.shape[0] != fn.shape[0]:
        raise ValueError(f"{labels.shape[0]} labels for {fn.shape[0]} features")
    if fn.shape[0] == 0:
        return FeatureStats(math.nan, math.nan, 0, 0)
    values, cents = _centres(fn, labels)
    pos = np.searchsorted(values, labels)
    intra = float(np.linalg.norm(fn - cents[pos], axis=1).mean())
    C = len(values)
    if C < 2:
        inter = math.nan
    else:
        d = np.linalg.norm(cents[:, None, :] - cents[None, :, :], axis=2)
        iu = np.triu_indices(C, k=1)
        inter = float(d[iu].mean())
    return FeatureStats(intra, inter, C, int(fn.shape[0]))
