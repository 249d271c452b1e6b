import numpy as np
import pytest

from trase.clustering import ClusteringError, cluster, filter_by_similarity, similarity_to_centre


def _blobs(n_per=300, k=4, d=8, noise=0.05, seed=0):
    rng = np.random.default_rng(seed)
    centres = np.eye(d)[:k] * 3
    x = np.concatenate([c + noise * rng.standard_normal((n_per, d)) for c in centres])
    return x.astype(np.float32), np.repeat(np.arange(k), n_per)


def _purity(labels, truth):
    # every found cluster lies inside one true group and every group maps to one cluster
    pairs = set(zip(labels.tolist(), truth.tolist()))
    return len(pairs) == len(set(labels.tolist())) == len(set(truth.tolist()))


@pytest.mark.parametrize("method,params", [("hdbscan", {}), ("dbscan", {"eps": 0.2}), ("kmeans", {"n_clusters": 4})])
def test_recovers_blobs(method, params):
    x, truth = _blobs()
    c = cluster(x, method=method, fraction=0.02, seed=0, **params)
    assert c.labels.shape == (len(x),) and c.labels.min() == 0
    assert _purity(c.labels, truth)
    assert c.centres.shape == (4, 8)
    np.testing.assert_allclose(np.linalg.norm(c.centres, axis=1), 1, atol=1e-5)


def test_deterministic_given_seed():
    x, _ = _blobs(seed=1)
    a, b = cluster(x, seed=5), cluster(x, seed=5)
    assert np.array_equal(a.labels, b.labels)


def test_degenerate_inputs():
    assert cluster(np.ones((1, 4))).labels.tolist() == [0]
    assert set(cluster(np.ones((50, 4))).labels.tolist()) == {0}  # all equal
    assert set(cluster(np.random.default_rng(0).random((5, 4)), min_sample=0).labels) == {0}  # < min_cluster_size
    assert cluster(np.zeros((0, 4))).labels.shape == (0,)
    c = cluster(np.zeros((20, 4)))  # zero-norm features
    assert np.isfinite(c.centres).all() and set(c.labels) == {0}
    with pytest.raises(ClusteringError, match="unknown clustering method"):
        cluster(np.ones((3, 2)), method="spectral")


def test_a_parameter_no_algorithm_reads_is_refused():
    x = np.random.default_rng(0).random((40, 4))
    with pytest.raises(ClusteringError, match="'cluster_selection_method' is read by no algorithm"):
        cluster(x, cluster_selection_method="leaf")
    # another algorithm's key is allowed: a run that switches algorithms keeps its preset's keys
    assert cluster(x, method="kmeans", n_clusters=3, min_cluster_size=50).n_clusters == 3


def test_filter_by_similarity():
    f = np.array([[1, 0], [1, 0.1], [0.2, 1.0], [0, 1], [0, 0]], np.float32)
    labels = np.array([0, 0, 0, 1, 1])
    sim = similarity_to_centre(f, labels)
    assert sim[0] > sim[2] and sim[4] == 0 and np.isfinite(sim).all()
    keep = filter_by_similarity(f, labels, 0.85)
    assert keep.tolist() == [True, True, False, True, False]


def test_hdbscan_epsilon_merges_what_splits_below_it():
    """The public code's cluster_selection_epsilon merges clusters that split below it (here three
    tight micro-clusters inside each of four groups), where scikit-learn's own merge fails
    under NumPy 2.4 (trase.epsilon_merge)."""
    rng = np.random.default_rng(0)
    groups = np.eye(8)[:4] * 3
    x = np.concatenate([g + 0.05 * rng.standard_normal(8) + 0.002 * rng.standard_normal((40, 8))
                        for g in groups for _ in range(3)]).astype(np.float32)
    truth = np.repeat(np.arange(4), 120)
    fine = cluster(x, method="hdbscan", fraction=1.0, min_sample=0, cluster_selection_epsilon=0.0)
    merged = cluster(x, method="hdbscan", fraction=1.0, min_sample=0, cluster_selection_epsilon=0.5)
    assert fine.n_clusters == 12 and merged.n_clusters == 4
    assert _purity(merged.labels, truth)
