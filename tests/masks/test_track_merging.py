"""Merging tracks that are one object in 3D (masks.track_merging): votes, similarity, the rule
that tracks shown side by side are never one."""

import numpy as np

from masks.track_merging import TrackVotes, merged_ids, track_similarity


def _similar(n, pairs):
    s = np.zeros((n, n))
    for (a, b), v in pairs.items():
        s[a, b] = s[b, a] = v
    return s


def test_fragments_on_the_same_gaussians_merge_and_ids_renumber_by_their_smallest():
    # tracks 1..4: 1 and 3 are one object, 2 and 4 another
    sim = _similar(4, {(0, 2): 0.9, (1, 3): 0.7, (0, 1): 0.1})
    new = merged_ids(sim, np.zeros((4, 4), bool), 0.5)
    assert new.tolist() == [0, 1, 2, 1, 2]


def test_tracks_shown_side_by_side_never_merge_however_similar():
    sim = _similar(2, {(0, 1): 0.99})
    together = np.array([[False, True], [True, False]])
    assert merged_ids(sim, together, 0.5).tolist() == [0, 1, 2]
    assert merged_ids(sim, np.zeros((2, 2), bool), 0.5).tolist() == [0, 1, 1]


def test_a_track_that_covered_two_objects_joins_one_of_them_not_both():
    # tracks 1 and 2 are two objects seen together; track 3 a mask that merged them in some views
    sim = _similar(3, {(0, 2): 0.8, (1, 2): 0.7})
    together = np.zeros((3, 3), bool)
    together[0, 1] = together[1, 0] = True
    new = merged_ids(sim, together, 0.5)
    assert new.tolist() == [0, 1, 2, 1]  # the most similar pair first; then 2 is apart from {1, 3}


def test_below_the_threshold_nothing_merges():
    sim = _similar(3, {(0, 1): 0.49, (1, 2): 0.3})
    assert merged_ids(sim, np.zeros((3, 3), bool), 0.5).tolist() == [0, 1, 2, 3]


def test_votes_and_their_similarity():
    votes = TrackVotes(n_gaussians=6)
    # view 1: tracks 1 (left) and 2 (right); gaussians 0, 1 on the left, 2 on the right
    ids = np.array([[1, 2]])
    votes.add(ids, np.array([0, 1, 2]), np.array([0, 0, 0]), np.array([0, 0, 1]))
    # view 2: track 3 alone on gaussians 0, 1 (a fragment of track 1); gaussian 5 on no track
    ids2 = np.array([[3, 0]])
    votes.add(ids2, np.array([0, 1, 5]), np.array([0, 0, 0]), np.array([0, 0, 1]))
    # view 3: track 4 shown, but no gaussian on it
    votes.add(np.array([[4, 0]]), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
    matrix, together = votes.matrices(4)
    assert matrix.shape == (6, 4) and matrix.toarray()[:, 0].tolist() == [1, 1, 0, 0, 0, 0]
    assert together[0, 1] and together[1, 0] and together.sum() == 2
    sim = track_similarity(matrix)
    assert np.isfinite(sim).all() and abs(sim[0, 2] - 1.0) < 1e-12 and sim[0, 1] == 0.0 and sim[3].max() == 0.0
    assert merged_ids(sim, together, 0.5).tolist() == [0, 1, 2, 1, 3]


def test_no_tracks_no_merging():
    votes = TrackVotes(n_gaussians=0)
    matrix, together = votes.matrices(0)
    assert matrix.shape == (0, 0) and merged_ids(track_similarity(matrix), together, 0.5).tolist() == [0]
