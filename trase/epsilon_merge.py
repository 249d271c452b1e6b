"""HDBSCAN's cluster_selection_epsilon merge (Malzer and Baum, 2020) on scikit-learn's tree.

The public code clusters with HDBSCAN(min_cluster_size=10, cluster_selection_epsilon=0.01): a
cluster that excess-of-mass selects but that splits off below the distance epsilon is replaced
by its lowest ancestor that splits off above it. scikit-learn (up to 1.9.1 at least) fails in
that merge under NumPy >= 2.4 (its issue #33219: a size-1 array read as a scalar), so whenever
the merge would change a cluster it raises, and where it does not raise the merge changed
nothing. The ``hdbscan`` package merges correctly but builds its own spanning tree, whose ties
break otherwise: its partitions differ from scikit-learn's at epsilon 0 too (adjusted Rand 0.67-0.99
on this project's features). So scikit-learn fits at epsilon 0 and this module applies the
merge to its condensed tree: wherever scikit-learn's merge does not fail the labels are its own.
"""

from __future__ import annotations

import numpy as np


def _lca(a: int, b: int, parent_of: dict[int, int]) -> int:
    """Lowest common ancestor of two nodes of the condensed tree."""
    seen = {a}
    while a in parent_of:
        a = parent_of[a]
        seen.add(a)
    while b not in seen:
        b = parent_of[b]
    return b


def _cluster_tree(condensed: np.ndarray) -> tuple[dict[int, int], dict[int, float]]:
    """The condensed tree's clusters: (child -> parent, child -> lambda at its birth = 1 / distance)."""
    tree = condensed[condensed["cluster_size"] > 1]
    children = tree["child"].tolist()
    return dict(zip(children, tree["parent"].tolist())), dict(zip(children, tree["value"].tolist()))


def selected_nodes(condensed: np.ndarray, labels: np.ndarray) -> dict[int, int]:
    """label -> the condensed tree's node selected for it: the lowest common ancestor of the
    nodes its points fell out of (every point below a selected node carries its label)."""
    points = condensed[condensed["cluster_size"] == 1]
    fell_from = dict(zip(points["child"].tolist(), points["parent"].tolist()))
    parent_of = _cluster_tree(condensed)[0]
    nodes: dict[int, int] = {}
    for p, label in enumerate(labels.tolist()):
        if label >= 0:
            node = fell_from[p]
            nodes[label] = node if label not in nodes else _lca(nodes[label], node, parent_of)
    return nodes


def _merged(leaf: int, epsilon: float, parent_of: dict[int, int], birth: dict[int, float], root: int) -> int:
    """The lowest ancestor of ``leaf`` that splits off above ``epsilon``, or the root's child on
    the way where there is none (a single cluster is not allowed)."""
    node = leaf
    while True:
        parent = parent_of[node]
        if parent == root:
            return node
        if 1.0 / birth[parent] > epsilon:
            return parent
        node = parent


def epsilon_labels(single_linkage_tree, labels: np.ndarray, min_cluster_size: int, epsilon: float) -> np.ndarray:
    """[S] labels of scikit-learn's HDBSCAN fitted at epsilon 0 (on ``single_linkage_tree``, its
    ``_single_linkage_tree_``) -> [S] labels after the epsilon merge, numbered as scikit-learn
    numbers them (by node id; -1 noise)."""
    labels = np.asarray(labels)
    if epsilon <= 0 or labels.max(initial=-1) < 0:
        return labels
    from sklearn.cluster._hdbscan._tree import _condense_tree, _do_labelling  # private: the merge only

    condensed = _condense_tree(single_linkage_tree, int(min_cluster_size))
    parent_of, birth = _cluster_tree(condensed)
    root = int(condensed["parent"].min())
    children: dict[int, list[int]] = {}
    for child, parent in parent_of.items():
        children.setdefault(parent, []).append(child)
    chosen: set[int] = set()
    below: set[int] = set()  # nodes under a merged cluster
    for leaf in sorted(selected_nodes(condensed, labels).values()):
        if 1.0 / birth[leaf] >= epsilon:
            chosen.add(leaf)
        elif leaf not in below:
            node = _merged(leaf, epsilon, parent_of, birth, root)
            chosen.add(node)
            stack = list(children.get(node, []))
            while stack:
                below.add(stack[-1])
                stack.extend(children.get(stack.pop(), []))
    chosen -= below
    numbering = {node: n for n, node in enumerate(sorted(chosen))}
    return np.asarray(_do_labelling(condensed, chosen, numbering, False, float(epsilon)), dtype=np.int64)


__all__ = ["epsilon_labels", "selected_nodes"]
