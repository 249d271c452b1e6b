"""Cluster learned gaussian features, assign every gaussian, filter by similarity.

As the public code: features are L2-normalised; a random ``fraction`` (2%) of the gaussians
is clustered with HDBSCAN(min_cluster_size=10, cluster_selection_epsilon=0.01) (the paper
says DBSCAN; DBSCAN and KMeans are options); every gaussian is then assigned by argmax cosine
similarity to the cluster centres, where the noise points' centroid is a centre too. Labels
are contiguous 0..C-1.

Small inputs: the subsample has at least ``min_sample`` points (or all N), since 2% of a
small synthetic scene is too few for density clustering; when the subsample is smaller than
the density method's min_cluster_size, or has fewer than 2 distinct points, everything is
one cluster.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from trase.epsilon_merge import epsilon_labels

METHODS = ("hdbscan", "dbscan", "kmeans")
# the keyword arguments each algorithm reads; a key none of them reads is an error (a typo, or an
# option of the library this module does not pass on, which would otherwise change nothing)
PARAMS = {"hdbscan": ("min_cluster_size", "min_samples", "cluster_selection_epsilon"),
          "dbscan": ("eps", "min_samples"),
          "kmeans": ("n_clusters", "n_init")}
NORM_EPS = 1e-12


class ClusteringError(ValueError):
    user_facing = True


def check_params(method: str, params: dict) -> None:
    """ClusteringError for an unknown ``method`` or a parameter no algorithm reads. A parameter
    of another algorithm is allowed: a run that switches algorithms keeps its preset's keys."""
    if method not in METHODS:
        raise ClusteringError(f"unknown clustering method {method!r}; choose one of {', '.join(METHODS)}")
    read = {k for keys in PARAMS.values() for k in keys}
    unknown = sorted(set(params) - read)
    if unknown:
        raise ClusteringError(f"clustering parameter {', '.join(map(repr, unknown))} is read by no algorithm; "
                              f"{method} reads {', '.join(PARAMS[method])}")


@dataclasses.dataclass
class Clustering:
    labels: np.ndarray  # [N] int64 in 0..C-1, every gaussian assigned
    centres: np.ndarray  # [C, D] float32 unit cluster centres (normalised mean of members)
    sample: np.ndarray  # [S] int64 ids of the gaussians that were clustered
    method: str
    params: dict

    @property
    def n_clusters(self) -> int:
        return int(self.centres.shape[0])


def normalise(features) -> np.ndarray:
    """[N, D] -> [N, D] float32 rows of unit norm (zero rows stay zero)."""
    f = np.asarray(features, dtype=np.float32)
    if hasattr(features, "detach"):
        f = features.detach().cpu().numpy().astype(np.float32)
    n = np.linalg.norm(f, axis=1, keepdims=True)
    return f / np.maximum(n, NORM_EPS)


def _centres(fn: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-label normalised mean. -> (label values [C], centres [C, D])."""
    values = np.unique(labels)
    cents = np.stack([fn[labels == v].mean(axis=0) for v in values]) if len(values) else np.zeros((0, fn.shape[1]), np.float32)
    return values, normalise(cents)


def _cluster_sample(x: np.ndarray, method: str, seed: int, params: dict) -> np.ndarray:
    """[S, D] normalised features -> [S] labels (-1 noise) from the chosen algorithm."""
    from sklearn import cluster as skc

    S = x.shape[0]
    if S == 0:
        return np.zeros(0, np.int64)
    distinct = np.unique(np.round(x, 6), axis=0).shape[0]
    if method == "kmeans":
        k = min(int(params.get("n_clusters", 10)), distinct)
        if k <= 1:
            return np.zeros(S, np.int64)
        km = skc.KMeans(n_clusters=k, n_init=int(params.get("n_init", 4)), random_state=seed)
        return km.fit_predict(x).astype(np.int64)
    if method == "hdbscan":
        mcs = int(params.get("min_cluster_size", 10))
        if S < max(mcs, 2) or distinct < 2:
            return np.zeros(S, np.int64)
        epsilon = float(params.get("cluster_selection_epsilon", 0.01))
        # epsilon 0 here, the merge after (trase.epsilon_merge: scikit-learn's own fails under NumPy 2.4)
        hd = skc.HDBSCAN(min_cluster_size=mcs, min_samples=params.get("min_samples"), copy=True)
        labels = hd.fit_predict(x)
        return epsilon_labels(hd._single_linkage_tree_, labels, mcs, epsilon).astype(np.int64)
    if method == "dbscan":
        ms = int(params.get("min_samples", 10))
        if S < max(ms, 2) or distinct < 2:
            return np.zeros(S, np.int64)
        db = skc.DBSCAN(eps=float(params.get("eps", 0.1)), min_samples=ms)
        return db.fit_predict(x).astype(np.int64)
    raise ClusteringError(f"unknown clustering method {method!r}; choose one of {', '.join(METHODS)}")


def cluster(
    features,
    method: str = "hdbscan",
    fraction: float = 0.02,
    seed: int = 0,
    min_sample: int = 500,
    **params,
) -> Clustering:
    """Cluster normalised features [N, D] and assign every gaussian to a cluster."""
    check_params(method, params)
    if not 0 < fraction <= 1:
        raise ClusteringError(f"clustering fraction must be in (0, 1], got {fraction}")
    fn = normalise(features)
    N, D = fn.shape
    if N == 0:
        return Clustering(np.zeros(0, np.int64), np.zeros((0, D), np.float32), np.zeros(0, np.int64), method, params)
    rng = np.random.default_rng(seed)
    S = min(N, max(math.ceil(fraction * N), int(min_sample)))
    sample = np.sort(rng.choice(N, size=S, replace=False)) if S < N else np.arange(N)
    sub_labels = _cluster_sample(fn[sample], method, seed, params)
    _, cents = _centres(fn[sample], sub_labels)  # noise (-1) centroid is a centre too
    labels = np.argmax(fn @ cents.T, axis=1).astype(np.int64)
    # drop centres nobody chose, keep labels contiguous; recompute centres from all members
    used = np.unique(labels)
    remap = np.full(cents.shape[0], -1, np.int64)
    remap[used] = np.arange(len(used))
    labels = remap[labels]
    _, cents = _centres(fn, labels)
    return Clustering(labels, cents.astype(np.float32), sample.astype(np.int64), method, dict(params))


def similarity_to_centre(features, labels: np.ndarray) -> np.ndarray:
    """[N] cosine similarity of each gaussian's normalised feature to its cluster's
    normalised mean feature (computed over all members)."""
    fn = normalise(features)
    labels = np.asarray(labels, dtype=np.int64)
    if fn.shape[0] == 0:
        return np.zeros(0, np.float32)
    values, cents = _centres(fn, labels)
    pos = np.searchsorted(values, labels)
    return np.einsum("nd,nd->n", fn, cents[pos]).astype(np.float32)


def filter_by_similarity(features, labels: np.ndarray, threshold: float) -> np.ndarray:
    """[N] bool keep mask: similarity to the cluster mean >= threshold (paper's post-filter).

    A zero-norm feature has similarity 0 and is kept only for thresholds <= 0."""
    return similarity_to_centre(features, labels) >= float(threshold)
