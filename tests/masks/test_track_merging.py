"""Merging tracks that are one object in 3D (masks.track_merging): votes, similarity, the rule
that tracks the same views show as two segments are not one."""

import numpy as np
import pytest

from masks.track_merging import TrackVotes, merged_ids, track_similarity


def _similar(n, pairs):
    s = np.zeros((n, n))
    for (a, b), v in pairs.items():
        s[a, b] = s[b, a] = v
    return s


def _shown(n, *views):
    """[V, n] bool: each view shows the tracks (0-based columns) listed."""
    m = np.zeros((len(views), n), bool)
    for i, cols in enumerate(views):
        m[i, list(cols)] = True
    return m


def test_fragments_on_the_same_gaussians_merge_and_ids_renumber_by_their_smallest():
    # tracks 1..4: 1 and 3 are one object, 2 and 4 another; 1 and 2 seen together, 3 and 4 too
    sim = _similar(4, {(0, 2): 0.9, (1, 3): 0.7, (0, 1): 0.1})
    new = merged_ids(sim, _shown(4, (0, 1), (2, 3)), 0.5)
    assert new.tolist() == [0, 1, 2, 1, 2]


def test_tracks_shown_by_one_view_never_merge_however_similar():
    sim = _similar(2, {(0, 1): 0.99})
    assert merged_ids(sim, _shown(2, (0, 1), (0,), (1,)), 0.5).tolist() == [0, 1, 2]
    assert merged_ids(sim, _shown(2, (0,), (1,)), 0.5).tolist() == [0, 1, 1]


def test_a_track_that_covered_two_objects_joins_one_of_them_not_both():
    # tracks 1 and 2 are two objects seen together; track 3 a mask that merged them in other views
    sim = _similar(3, {(0, 2): 0.8, (1, 2): 0.7})
    new = merged_ids(sim, _shown(3, (0, 1), (2,)), 0.5)
    assert new.tolist() == [0, 1, 2, 1]  # the most similar pair first; then 2 is seen with {1, 3}


def test_a_group_is_seen_wherever_its_members_are():
    # 1 and 3 merge first (0.8); 2 was never seen with 1, only with 3: the group {1, 3} is
    sim = _similar(3, {(0, 2): 0.8, (0, 1): 0.7})
    assert merged_ids(sim, _shown(3, (1, 2), (0,)), 0.5).tolist() == [0, 1, 2, 1]


def test_a_few_shared_views_are_allowed_up_to_the_share():
    # tracks 1 and 2 one object, cut in two segments in 1 of the 10 views of track 2
    sim = _similar(2, {(0, 1): 0.9})
    shown = _shown(2, *([(0,)] * 20 + [(1,)] * 9 + [(0, 1)]))
    assert merged_ids(sim, shown, 0.5, max_together=0.0).tolist() == [0, 1, 2]
    assert merged_ids(sim, shown, 0.5, max_together=0.1).tolist() == [0, 1, 1]
    assert merged_ids(sim, shown, 0.5, max_together=0.09).tolist() == [0, 1, 2]


def test_below_the_threshold_nothing_merges_and_the_threshold_must_be_positive():
    sim = _similar(3, {(0, 1): 0.49, (1, 2): 0.3})
    assert merged_ids(sim, _shown(3, (0,), (1,), (2,)), 0.5).tolist() == [0, 1, 2, 3]
    with pytest.raises(ValueError, match="min_cosine"):
        merged_ids(sim, _shown(3, (0,)), 0.0)


def test_votes_and_their_similarity():
    votes = TrackVotes(n_gaussians=6)
    # view 1: tracks 1 (left) and 2 (right); gaussians 0, 1 on the left, 2 on the right
    votes.add(np.array([[1, 2]]), np.array([0, 1, 2]), np.array([0, 0, 0]), np.array([0, 0, 1]))
    # view 2: track 3 alone on gaussians 0, 1 (a fragment of track 1); gaussian 5 on no track
    votes.add(np.array([[3, 0]]), np.array([0, 1, 5]), np.array([0, 0, 0]), np.array([0, 0, 1]))
    # view 3: track 4 shown, but no gaussian on it
    votes.add(np.array([[4, 0]]), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
    matrix, shown = votes.matrices(4)
    assert matrix.shape == (6, 4) and matrix.toarray()[:, 0].tolist() == [1, 1, 0, 0, 0, 0]
    assert shown.toarray().tolist() == [[True, True, False, False], [False, False, True, False],
                                        [False, False, False, True]]
    sim = track_similarity(matrix).toarray()
    assert np.isfinite(sim).all() and abs(sim[0, 2] - 1.0) < 1e-12 and sim[0, 1] == 0.0 and sim[3].max() == 0.0
    assert np.allclose(np.diag(sim), 0.0)
    assert merged_ids(track_similarity(matrix), shown, 0.5).tolist() == [0, 1, 2, 1, 3]


def test_no_tracks_no_merging():
    matrix, shown = TrackVotes(n_gaussians=0).matrices(0)
    assert matrix.shape == (0, 0) and shown.shape == (0, 0)
    assert merged_ids(track_similarity(matrix), shown, 0.5).tolist() == [0]
