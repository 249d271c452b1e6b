import numpy as np
import pytest
from sklearn.cluster import HDBSCAN

from trase.epsilon_merge import epsilon_labels, selected_nodes


def _nested(seed: int) -> np.ndarray:
    """Four groups of three sub-clusters of random spreads: splits at many distances."""
    rng = np.random.default_rng(seed)
    parts = []
    for _ in range(4):
        base = rng.normal(size=8) * 3
        for _ in range(3):
            sub = base + rng.normal(size=8) * rng.choice([0.05, 0.5, 2.0])
            parts.append(sub + rng.normal(size=(int(rng.integers(15, 60)), 8)) * rng.choice([0.002, 0.02, 0.2]))
    return np.concatenate(parts)


def _fit(x, mcs):
    hd = HDBSCAN(min_cluster_size=mcs, copy=True)
    return hd, hd.fit_predict(x)


def test_epsilon_zero_keeps_scikit_learns_labels():
    hd, labels = _fit(_nested(0), 10)
    assert np.array_equal(epsilon_labels(hd._single_linkage_tree_, labels, 10, 0.0), labels)


def test_selected_nodes_label_every_point_below_them():
    from sklearn.cluster._hdbscan._tree import _condense_tree, _do_labelling

    hd, labels = _fit(_nested(1), 10)
    condensed = _condense_tree(hd._single_linkage_tree_, 10)
    nodes = selected_nodes(condensed, labels)
    assert sorted(nodes) == sorted(set(labels.tolist()) - {-1})
    numbering = {node: label for label, node in nodes.items()}
    assert np.array_equal(_do_labelling(condensed, set(nodes.values()), numbering, False, 0.0), labels)


@pytest.mark.parametrize("seed", range(6))
def test_merges_as_scikit_learn_where_its_own_merge_runs(seed):
    """Under NumPy < 2.4 scikit-learn's merge runs and the labels must be equal; under 2.4 it
    fails whenever it would merge, and where it runs it merged nothing."""
    x, merged = _nested(seed), 0
    for mcs in (5, 10, 20):
        hd, labels = _fit(x, mcs)
        for eps in (0.05, 0.3, 1.0, 3.0):
            ours = epsilon_labels(hd._single_linkage_tree_, labels, mcs, eps)
            assert set(ours.tolist()) <= set(range(-1, len(set(labels.tolist()))))
            assert (ours == -1).sum() <= (labels == -1).sum()  # a merge only absorbs, never drops
            merged += len(set(ours.tolist())) < len(set(labels.tolist()))
            try:
                theirs = HDBSCAN(min_cluster_size=mcs, cluster_selection_epsilon=eps, copy=True).fit_predict(x)
            except TypeError:  # scikit-learn #33219
                continue
            assert np.array_equal(ours, theirs)
    assert merged  # the data has splits below the epsilons

