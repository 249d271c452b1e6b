"""Tracks that are one object in 3D, merged: the classical tracker's last step.

A tracker that follows masks from view to view fragments an object wherever two views segment
it differently (another camera of a rig splits it otherwise, a mask is missed for longer than
the memory): the object then carries several track ids, and a method that classifies ids learns
each fragment as a class of its own. The views agree on where the object *is*, though: its
gaussians. Each view votes, for each gaussian it sees on its surface, for the track its pixel
carries (``TrackVotes.add``); two tracks whose votes fall on the same gaussians (cosine of their
vote columns at least ``min_cosine``) are one object, unless some view shows them side by side
as two segments, which no fragment of one track ever is (``merged_ids``).

Merging is greedy, the most similar pair first, between groups of tracks, and a group never
takes a track that appears beside one of its members in any view, so a mask that merged two
objects in some views cannot chain them into one track.
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

    def add(self, ids: np.ndarray, gaussians: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> None:
        """One view: ``ids`` [H, W] its track ids (0: none); ``gaussians`` [M] the gaussians it
        sees on its surface, at pixels (``rows``, ``cols``) [M]."""
        k = ids[rows, cols].astype(np.int64)
        sel = k > 0
        self._gaussians.append(np.asarray(gaussians, np.int64)[sel])
        self._tracks.append(k[sel])
        present = np.unique(ids)
        self._present.append(present[present > 0].astype(np.int64))

    def matrices(self, n_tracks: int):
        """(votes: scipy CSR [N, T], a gaussian's votes per track (column t-1 is track t);
        together: [T, T] bool, tracks shown side by side in some view)."""
        from scipy import sparse

        g = np.concatenate(self._gaussians) if self._gaussians else np.zeros(0, np.int64)
        t = np.concatenate(self._tracks) if self._tracks else np.zeros(0, np.int64)
        votes = sparse.coo_matrix((np.ones(g.shape[0], np.float64), (g, t - 1)),
                                  shape=(self.n_gaussians, n_tracks)).tocsr()
        together = np.zeros((n_tracks, n_tracks), bool)
        for p in self._present:
            if p.shape[0] > 1:
                together[np.ix_(p - 1, p - 1)] = True
        np.fill_diagonal(together, False)
        return votes, together


def track_similarity(votes) -> np.ndarray:
    """[T, T] cosine of the tracks' vote columns (0 for a track without votes)."""
    gram = np.asarray((votes.T @ votes).todense(), np.float64)
    norm = np.sqrt(np.diag(gram))
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = gram / np.outer(norm, norm)
    cos[~np.isfinite(cos)] = 0.0
    np.fill_diagonal(cos, 0.0)
    return cos


def merged_ids(similarity: np.ndarray, together: np.ndarray, min_cosine: float) -> np.ndarray:
    """[T + 1] new id of each track id 0..T (0 stays 0): pairs with similarity >= ``min_cosine``
    joined most similar first, between groups none of whose members appear together in any view;
    the groups numbered 1..K by their smallest track id."""
    t = similarity.shape[0]
    parent = np.arange(t)

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    apart = together.copy()  # between roots: some member of one appears beside one of the other
    a, b = np.nonzero(np.triu(similarity >= min_cosine, 1))
    for i in np.argsort(-similarity[a, b], kind="stable"):
        ra, rb = root(int(a[i])), root(int(b[i]))
        if ra == rb or apart[ra, rb]:
            continue
        lo, hi = min(ra, rb), max(ra, rb)
        parent[hi] = lo
        apart[lo] |= apart[hi]
        apart[:, lo] |= apart[:, hi]
    roots = np.array([root(i) for i in range(t)], np.int64)
    number = {r: k + 1 for k, r in enumerate(sorted(set(roots.tolist())))}
    return np.concatenate([[0], [number[r] for r in roots.tolist()]]).astype(np.int64)


__all__ = ["TrackVotes", "merged_ids", "track_similarity"]
