"""Positive and negative clicks (trase.prompts.clicks_to_clusters): a negative click removes the
selected cluster under it and keeps it out, so a later positive click there picks the best
cluster not ruled out."""

import numpy as np
import pytest

from benchmark.protocol.prompts import interior_points
from tests.trase.helpers import exact_masks, tiny_scene
from trase.prompts import CLICK_RULES, Click, PromptError, click_to_cluster, clicks_to_clusters, select_in_order


def _split_object(ids: np.ndarray) -> np.ndarray:
    """Object 0's gaussians in two interleaved clusters (0 and 2): a click on it is blended."""
    labels = ids.astype(np.int64).copy()
    zero = np.flatnonzero(ids == 0)
    labels[zero[1::2]] = 2
    return labels


def _setup():
    gm, deform, ids, views = tiny_scene()
    cam = views[1].camera
    (u, v), = interior_points(exact_masks(gm, deform, ids, views[1]).masks[0], 1)[:1]
    labels = _split_object(ids)
    features = np.eye(3)[np.maximum(labels, 0)] + 0.01  # [N, 3]: each cluster its own direction
    return gm, deform, cam, Click(u, v), labels, features


@pytest.mark.parametrize("rule", CLICK_RULES)
def test_an_excluded_cluster_is_never_chosen_and_the_next_best_is(rule):
    gm, deform, cam, click, labels, features = _setup()
    kw = {"rule": rule, "features": features}
    first = click_to_cluster(gm, deform, cam, click, labels, **kw)
    assert first in (0, 2)
    second = click_to_cluster(gm, deform, cam, click, labels, exclude={first}, **kw)
    assert second == 2 - first  # the object's other cluster
    assert click_to_cluster(gm, deform, cam, click, labels, exclude={0, 2}, **kw) not in (0, 2)


@pytest.mark.parametrize("rule", ["depth", "weight", "feature"])
def test_a_negative_click_removes_and_keeps_out_and_a_later_positive_click_picks_another(rule):
    gm, deform, cam, click, labels, features = _setup()
    kw = {"rule": rule, "features": features}
    negative = Click(click.u, click.v, positive=False)
    selected, per_click = clicks_to_clusters(gm, deform, [cam] * 3, [click, negative, click], labels, **kw)
    first = per_click[0]
    assert per_click == [first, first, 2 - first] and selected == [2 - first]
    # all positive: the set of each click's own cluster, as one click at a time gives
    assert clicks_to_clusters(gm, deform, [cam], [click], labels, **kw) == ([first], [first])


def test_a_negative_click_with_nothing_selected_rules_out_the_cluster_under_it():
    gm, deform, cam, click, labels, _ = _setup()
    negative = Click(click.u, click.v, positive=False)
    selected, per_click = clicks_to_clusters(gm, deform, [cam, cam], [negative, click], labels, rule="weight")
    assert per_click[1] == 2 - per_click[0] and selected == [per_click[1]]


def test_clicks_need_a_camera_each():
    gm, deform, cam, click, labels, _ = _setup()
    with pytest.raises(PromptError, match="2 clicks need as many cameras, got 1"):
        clicks_to_clusters(gm, deform, [cam], [click, click], labels)



@pytest.mark.parametrize("rule", ["depth", "weight", "feature"])
def test_a_second_click_on_a_selected_cluster_adds_the_next_one_under_it_only_where_asked(rule):
    gm, deform, cam, click, labels, features = _setup()
    kw = {"rule": rule, "features": features}
    first = click_to_cluster(gm, deform, cam, click, labels, **kw)
    # the paper's: one click, one cluster; the same click again changes nothing
    assert clicks_to_clusters(gm, deform, [cam] * 2, [click, click], labels, **kw) == ([first], [first, first])
    # "next": the object's other cluster under the same pixel
    selected, per_click = clicks_to_clusters(gm, deform, [cam] * 2, [click, click], labels, on_selected="next", **kw)
    assert per_click == [first, 2 - first] and selected == [0, 2]


def test_next_keeps_out_what_a_negative_click_ruled_out_and_adds_nothing_where_nothing_is_left():
    gm, deform, cam, click, labels, _ = _setup()
    negative = Click(click.u, click.v, positive=False)
    clicks = [click, negative, click, click]  # select, remove and rule out, select the other, again
    first = click_to_cluster(gm, deform, cam, click, labels, rule="weight")
    # the last click: no third cluster is drawn under the pixel, so nothing is added
    assert clicks_to_clusters(gm, deform, [cam] * 4, clicks, labels, rule="weight", on_selected="next") == (
        [2 - first], [first, first, 2 - first, 2 - first])


def test_select_in_order_on_selected_by_name():
    with pytest.raises(PromptError, match="unknown on_selected 'more'"):
        select_in_order([Click(0, 0)], lambda i, exclude: 0, {0}, on_selected="more")
    # a pick that finds nothing else keeps the click's cluster on record
    assert select_in_order([Click(0, 0)] * 2, lambda i, exclude: 0 if 0 not in exclude else -1, {0},
                           on_selected="next") == ([0], [0, 0])
