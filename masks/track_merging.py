"""Tracks that are one object in 3D, merged: the classical tracker's last step.

A tracker that follows masks from view to view fragments an object wherever two views segment
it differently (another camera of a rig splits it otherwise, a mask is missed for longer than
the memory): the object then carries several track ids, and a method that classifies ids learns
each fragment as a class of its own. The views agree on where the object *is*, though: its
gaussians. Each view votes, for each gaussian it sees on its surface, for the track its pixel
carries (``TrackVotes.add``); two tracks whose votes fall on the same gaussians (cosine of their
vote columns at least ``min_cosine``) are one object, unless the same views show them as two
segments too often: in more than ``max_together`` of the views of the one seen in fewer (an
object's fragments share a view only where its mask came cut in two there; two objects that are
seen together share most of theirs) (``merged_ids``).

Merging is greedy, the most similar pair first, between groups of tracks, a group being seen
wherever one of its members is, so a mask that merged two neighbours in some views cannot chain
them into one track.
"""

from __future__ import annotations

import numpy as np


class TrackVotes:
    """Per view, which track each visible gaussian showed, and which tracks appeared together."""

    def __init__(self, n_gaussians: int):
        self.n_gaussians = int(n_gaussians)
        self._gaussians: list[np.ndarray] = []  # per view [M] gaussian indices
        self._tracks: list[np.ndarray] = []  # per view [M] track ids (>= 1)
        self._present: list[np.ndarray] = []  # per view, the track ids it shows

    def add(self, ids: np.ndarray, gaussians: np.ndarray, rows: np.ndarray, cols: np.ndarray,
            present: np.ndarray | None = None) -> None:
        """One view: ``ids`` [H, W] its track ids (0: none); ``gaussians`` [M] the gaussians it
        sees on its surface, at pixels (``rows``, ``cols``) [M]; ``present``: the ids the view
        shows, where the caller knows them (else read from ``ids``)."""
        k = ids[rows, cols].astype(np.int32)
        sel = k > 0
        self._gaussians.append(np.asarray(gaussians, np.int32)[sel])
        self._tracks.append(k[sel])
        p = np.unique(ids) if present is None else np.unique(np.asarray(present))
        self._present.append(p[p > 0].astype(np.int64))

    def matrices(self, n_tracks: int):
        """(votes: scipy CSR [N, T], a gaussian's votes per track (column t-1 is track t);
        shown: scipy CSC [V, T] bool, the tracks each view shows)."""
        from scipy import sparse

        g = np.concatenate(self._gaussians) if self._gaussians else np.zeros(0, np.int32)
        t = np.concatenate(self._tracks) if self._tracks else np.zeros(0, np.int32)
        votes = sparse.csr_matrix((np.ones(g.shape[0], np.float64), (g, t.astype(np.int64) - 1)),
                                  shape=(self.n_gaussians, n_tracks))
        rows = np.repeat(np.arange(len(self._present)), [p.shape[0] for p in self._present])
        cols = np.concatenate(self._present) - 1 if self._present else np.zeros(0, np.int64)
        shown = sparse.csc_matrix((np.ones(rows.shape[0], bool), (rows, cols)), shape=(len(self._present), n_tracks))
        return votes, shown


def track_similarity(votes):
    """scipy CSR [T, T]: cosine of the tracks' vote columns, stored only where two tracks share
    a gaussian (a track without votes is similar to none; no dense T x T product)."""
    from scipy import sparse

    norm = np.sqrt(np.asarray(votes.multiply(votes).sum(0)).ravel())
    scale = sparse.diags(np.where(norm > 0, 1.0 / np.maximum(norm, 1e-300), 0.0))
    unit = votes @ scale
    cos = (unit.T @ unit).tocsr()
    cos.setdiag(0.0)
    cos.eliminate_zeros()
    return cos


def merged_ids(similarity, shown, min_cosine: float, max_together: float = 0.0) -> np.ndarray:
    """[T + 1] new id of each track id 0..T (0 stays 0). ``similarity`` [T, T] (dense or scipy
    sparse), ``shown`` [V, T] (dense or scipy sparse) the tracks each view shows. Pairs with
    similarity >= ``min_cosine`` (> 0) are joined, most similar first, between groups that are
    shown by the same view in at most ``max_together`` of the views of the one seen in fewer
    (0: in none); a group is seen in the views of any of its members. Groups are numbered 1..K
    by their smallest track id."""
    from scipy import sparse

    if not min_cosine > 0:
        raise ValueError(f"min_cosine must be > 0 (0 would join tracks that share no gaussian), got {min_cosine}")
    shown = sparse.csc_matrix(shown)
    t = shown.shape[1]
    views = [set(shown.indices[shown.indptr[k]:shown.indptr[k + 1]].tolist()) for k in range(t)]  # per root
    parent = np.arange(t)

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    upper = sparse.triu(sparse.csr_matrix(similarity), 1).tocoo()
    keep = upper.data >= min_cosine
    a, b, cos = upper.row[keep], upper.col[keep], upper.data[keep]
    for i in np.argsort(-cos, kind="stable"):
        ra, rb = root(int(a[i])), root(int(b[i]))
        if ra == rb:
            continue
        va, vb = views[ra], views[rb]
        if len(va & vb) > max_together * min(len(va), len(vb)):
            continue
        lo, hi = min(ra, rb), max(ra, rb)
        parent[hi] = lo
        views[lo] = va | vb
        views[hi] = set()
    roots = np.array([root(i) for i in range(t)], np.int64)
    number = {r: k + 1 for k, r in enumerate(sorted(set(roots.tolist())))}
    return np.concatenate([[0], [number[r] for r in roots.tolist()]]).astype(np.int64)


__all__ = ["TrackVotes", "merged_ids", "track_similarity"]
