"""The robot user (benchmark.protocol.corrective): where its next click goes, when it stops, and
how many clicks a curve needs."""

import numpy as np
import pytest

from benchmark.protocol.corrective import check_frames, clicks_to_reach, corrective_clicks, iou, next_click
from trase.prompts import Click

H, W = 20, 30


def _box(r0, r1, c0, c1):
    m = np.zeros((H, W), bool)
    m[r0:r1, c0:c1] = True
    return m


FRAMES = {0: ("v0", 0.0), 3: ("v3", 0.5)}


def test_a_missed_region_gets_a_positive_click_at_its_most_interior_pixel():
    gt = _box(2, 9, 3, 10)  # 7x7, centre pixel (row 5, column 6)
    c = next_click({0: np.zeros((H, W), bool), 3: np.zeros((H, W), bool)}, {0: gt, 3: np.zeros((H, W), bool)}, FRAMES)
    assert (c.u, c.v, c.positive, c.view, c.view_index, c.time) == (6.5, 5.5, True, "v0", 0, 0.0)


def test_the_largest_error_of_the_click_frames_wins_and_a_wrong_region_gets_a_negative_click():
    gt = _box(2, 9, 3, 10)
    wrong = gt | _box(10, 20, 10, 30)  # 200 px selected that are not the object, in frame 3
    c = next_click({0: gt, 3: wrong}, {0: gt, 3: gt}, FRAMES)
    assert not c.positive and c.view_index == 3 and not gt[int(c.v), int(c.u)] and wrong[int(c.v), int(c.u)]
    assert next_click({0: gt, 3: gt}, {0: gt, 3: gt}, FRAMES) is None  # nothing to correct


def _region_predictor(labels: np.ndarray):
    """A method whose objects are the regions of ``labels``: a positive click adds the region
    under it, a negative one removes it."""
    def predict(clicks):
        chosen = set()
        for c in clicks:
            k = int(labels[int(c.v), int(c.u)])
            chosen = chosen | {k} if c.positive else chosen - {k}
        chosen.discard(0)
        return {i: np.isin(labels, sorted(chosen)) for i in (0,)}
    return predict


def test_it_corrects_until_the_target_and_records_the_curve():
    labels = np.zeros((H, W), np.int64)
    labels[2:9, 3:10], labels[10:18, 12:28], labels[0:6, 20:30] = 1, 2, 3
    gt = {0: np.isin(labels, [1, 2])}
    first = [Click(6.5, 5.5, "v0", 0.0, 0)]  # on region 1 only
    r = corrective_clicks(first, _region_predictor(labels), gt, budget=3, target=0.9)
    clicks, curve = r.clicks, r.curve
    assert len(clicks) == 2 and clicks[1].positive and labels[int(clicks[1].v), int(clicks[1].u)] == 2
    assert curve[0] == pytest.approx(iou(labels == 1, gt[0])) and curve[1] == 1.0


def test_a_wrong_first_click_is_undone_by_a_negative_one_and_the_budget_bounds_it():
    labels = np.zeros((H, W), np.int64)
    labels[2:9, 3:10], labels[10:18, 12:28] = 1, 2
    gt = {0: labels == 1}
    first = [Click(20.5, 14.5, "v0", 0.0, 0)]  # on region 2: everything wrong
    r = corrective_clicks(first, _region_predictor(labels), gt, budget=3, target=0.9)
    clicks, curve = r.clicks, r.curve
    assert [c.positive for c in clicks] == [True, False, True] and curve == [0.0, 0.0, 1.0]
    # a prediction no click changes: the click is undone, its region left alone; nothing else to click
    never = corrective_clicks(first, lambda clicks: {0: np.zeros((H, W), bool)}, gt, budget=2, target=0.9)
    assert never.clicks == first and [kept for _, kept in never.spent] == [False] and never.curve == [0.0, 0.0]
    cols = np.arange(W)[None, :]  # each click adds a column of the object: the budget stops it
    changing = corrective_clicks(first, lambda clicks: {0: gt[0] & (cols < 3 + len(clicks))}, gt, budget=2,
                                 target=0.9)
    assert len(changing.clicks) == 3 and changing.curve == pytest.approx([1 / 7, 2 / 7, 3 / 7])


def test_a_click_that_makes_things_worse_is_undone_and_its_region_left_alone():
    # region 2 straddles the object: 40 px inside it, 80 outside; the wrong part (80 px) is the
    # largest error, but removing region 2 loses more than it gains: undone, then the missed
    # region 3 (inside the object, 12 px) gets the next click
    labels = np.zeros((H, W), np.int64)
    labels[2:12, 2:6], labels[2:12, 6:18], labels[14:17, 2:6] = 1, 2, 3
    gt = {0: np.isin(labels, [1, 3]) | ((labels == 2) & (np.arange(W)[None, :] < 10))}
    first = [Click(3.5, 5.5, "v0", 0.0, 0), Click(12.5, 5.5, "v0", 0.0, 0)]  # regions 1 and 2
    r = corrective_clicks(first, _region_predictor(labels), gt, budget=4, target=0.95)
    assert [(kept, c.positive, int(labels[int(c.v), int(c.u)])) for c, kept in r.spent][:2] == [
        (False, False, 2), (True, True, 3)]
    assert r.clicks == [*first, r.spent[1][0]] and r.curve[1] == r.curve[0] < r.curve[2]


def test_clicks_to_reach_counts_the_budget_plus_one_where_the_target_is_never_reached():
    assert clicks_to_reach([0.5, 0.86, 0.95], first=2, target=0.85, budget=3) == 3
    assert clicks_to_reach([0.5, 0.86, 0.95], first=2, target=0.90, budget=3) == 4
    assert clicks_to_reach([0.5, 0.6], first=2, target=0.85, budget=3) == 6
    with pytest.raises(ValueError, match="at least one click"):
        corrective_clicks([], lambda c: {}, {}, budget=1, target=0.9)


def test_a_click_that_gains_less_than_the_minimum_is_undone():
    labels = np.zeros((H, W), np.int64)
    labels[2:12, 2:12], labels[2:3, 12:14] = 1, 2  # region 2: 2 px of the object
    gt = {0: np.isin(labels, [1, 2])}
    first = [Click(6.5, 6.5, "v0", 0.0, 0)]
    kept = corrective_clicks(first, _region_predictor(labels), gt, budget=2, target=1.0)
    assert [k for _, k in kept.spent] == [True] and kept.curve[-1] == 1.0
    strict = corrective_clicks(first, _region_predictor(labels), gt, budget=2, target=1.0, min_gain=0.05)
    assert [k for _, k in strict.spent] == [False] and strict.clicks == first


def test_check_frames_spread_over_the_sequence_and_skip_the_click_frames():
    assert check_frames(50, [0], 2) == [17, 33]  # a third and two thirds of the 49 other frames
    assert check_frames(10, [3], 1) == [5]
    assert check_frames(3, [1], 5) == [0, 2]  # no more frames than the sequence has
    assert check_frames(1, [0], 2) == [] and check_frames(50, [0], 0) == []


def test_a_click_that_helps_its_frame_and_costs_a_check_frame_more_is_undone():
    """Region 2 is the object in the click frame (0) but covers background in check frame 5: a
    person watching frame 5 would undo the click; the click frame alone would keep it."""
    labels = np.zeros((H, W), np.int64)
    labels[2:9, 3:10], labels[10:12, 12:15] = 1, 2
    labels_later = labels.copy()
    labels_later[10:20, 0:30] = 2  # in frame 5 region 2 is a wall of 300 px
    gt = {0: np.isin(labels, [1, 2]), 5: labels_later == 1}

    def predict(clicks):
        chosen = {int(labels[int(c.v), int(c.u)]) for c in clicks} - {0}
        return {0: np.isin(labels, sorted(chosen)), 5: np.isin(labels_later, sorted(chosen))}

    first = [Click(6.5, 5.5, "v0", 0.0, 0)]
    alone = corrective_clicks(first, lambda c: {0: predict(c)[0]}, {0: gt[0]}, budget=1, target=1.0)
    assert [k for _, k in alone.spent] == [True]  # the click frame alone keeps it
    watched = corrective_clicks(first, predict, gt, budget=1, target=1.0)
    assert [k for _, k in watched.spent] == [False] and watched.clicks == first
    assert watched.curve[1] == watched.curve[0] < 1.0  # the undone click leaves the mean IoU of both frames


def test_after_an_undone_click_its_region_is_clicked_again_away_from_it_only_with_a_radius():
    gt = _box(2, 6, 2, 26)  # a 4 x 24 px bar, missed; its first interior pixel (row 3, column 3)
    none = np.zeros((H, W), bool)
    preds, gts = {0: none, 3: none}, {0: gt, 3: none}
    first = next_click(preds, gts, FRAMES)
    assert (first.u, first.v) == (3.5, 3.5)
    assert next_click(preds, gts, FRAMES, undone=[first]) is None  # the whole region left alone
    again = next_click(preds, gts, FRAMES, undone=[first], undone_radius=2.0)
    assert again.positive and gt[int(again.v), int(again.u)]
    assert (again.u - first.u) ** 2 + (again.v - first.v) ** 2 > 2.0**2  # outside the radius
    # a negative click undone does not keep a positive one out
    assert next_click(preds, gts, FRAMES, undone=[Click(3.5, 3.5, "v0", 0.0, 0, False)]) == first


def test_with_a_radius_a_region_is_left_alone_once_its_tries_were_undone():
    gt = _box(2, 6, 2, 26) | _box(10, 13, 2, 8)  # a 4 x 24 px bar and a 3 x 6 px box, both missed
    none = np.zeros((H, W), bool)
    preds, gts = {0: none, 3: none}, {0: gt, 3: none}
    first = next_click(preds, gts, FRAMES)
    assert gt[:6][int(first.v), int(first.u)]  # the bar, the larger region
    second = next_click(preds, gts, FRAMES, undone=[first], undone_radius=2.0, region_tries=2)
    assert gt[:6][int(second.v), int(second.u)]  # one try undone of two: the bar again, away from it
    undone = [first, second]
    for tries, in_bar in ((0, True), (3, True), (2, False)):  # 0: no limit
        c = next_click(preds, gts, FRAMES, undone=undone, undone_radius=2.0, region_tries=tries)
        assert (int(c.v) < 6) == in_bar, tries
    # without a radius the first undone click already leaves the bar alone, whatever the tries
    c = next_click(preds, gts, FRAMES, undone=[first], region_tries=2)
    assert int(c.v) >= 10
