"""CGC inference: patch query, similarity threshold selection, end to end on a tiny scene."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.cgc_inference import (
    CGCInferenceError,
    patch_query,
    select_by_clicks,
    similarity_select,
)
from benchmark.protocol.prompts import interior_points
from tests.trase.helpers import exact_masks, tiny_scene
from trase.prompts import Click
from trase.segment import render_masks


def test_patch_query_is_centred_and_clipped():
    fmap = torch.arange(7 * 8, dtype=torch.float32).reshape(7, 8, 1)  # value = 8 r + c
    # centred 5x5 at (r=3, c=4): rows 1..5, cols 2..6 -> mean 8*3 + 4
    assert float(patch_query(fmap, 4.5, 3.5)[0]) == pytest.approx(28.0)
    # corner (0, 0): rows 0..2, cols 0..2 -> mean 8 + 1
    assert float(patch_query(fmap, 0.2, 0.7)[0]) == pytest.approx(9.0)
    with pytest.raises(CGCInferenceError, match="outside"):
        patch_query(fmap, 8.0, 1.0)
    with pytest.raises(CGCInferenceError, match="patch"):
        patch_query(fmap, 1.0, 1.0, patch=0)


def test_similarity_select_threshold_and_union():
    f = torch.tensor([[1.0, 0.0], [0.8, 0.6], [0.0, 1.0], [0.0, 0.0], [-1.0, 0.0]])
    # cos with (1, 0): 1, .8, 0, 0, -1
    assert similarity_select(f, torch.tensor([[2.0, 0.0]]), 0.7).tolist() == [
        True,
        True,
        False,
        False,
        False,
    ]
    assert similarity_select(f, torch.tensor([[2.0, 0.0]]), 0.9).tolist() == [
        True,
        False,
        False,
        False,
        False,
    ]
    both = similarity_select(f, torch.tensor([[1.0, 0.0], [0.0, 1.0]]), 0.9)
    assert both.tolist() == [True, False, True, False, False]
    assert not similarity_select(f, torch.zeros(1, 2)).any()  # empty-space query
    assert similarity_select(f, torch.zeros(0, 2)).shape == (5,)
    with pytest.raises(CGCInferenceError, match="threshold"):
        similarity_select(f, f, 2.0)


def test_click_selects_the_object_and_renders_its_mask():
    gm, deform, ids, views = tiny_scene()
    feats = torch.nn.functional.one_hot(torch.from_numpy(ids).long(), 2).float() + 0.05
    cam = views[1].camera
    obj0 = exact_masks(gm, deform, ids, views[1]).masks[0]
    ((u, v),) = interior_points(obj0, 1)[:1]
    sel = select_by_clicks(gm, deform, feats, cam, [Click(u, v)])
    assert np.array_equal(sel, ids == 0)
    pred = render_masks(gm, deform, sel, [cam])[0]
    assert (pred & obj0).sum() / max((pred | obj0).sum(), 1) > 0.8
    assert not select_by_clicks(gm, deform, feats, cam, []).any()
    with pytest.raises(CGCInferenceError, match="features must be"):
        select_by_clicks(gm, deform, feats[:3], cam, [Click(u, v)])
