"""Hand-computed selections and losses for the hard and all mining ablations."""

from __future__ import annotations

import math

import pytest
import torch
from baseline_helpers import make_sample

from baselines.all_mining import AllMining, all_mining_loss
from baselines.hard_mining import HardMining, hard_mining_loss, hard_pairs
from trase.objectives import ObjectiveInputError, get_objective, pair_stats
from trase.objectives.soft import SoftMining


def _case():
    # pixels 0, 1, 3 in mask A (area 10); pixel 2 in mask B (area 20); pixel 4 in no mask.
    # Mean areas: A pixels 10, B pixel 20 -> S = s s^T; W = 400 / S: AA 4, AB 2, BB 1
    # -> rescaled to [1, 10]: AA 10, AB 4, BB 1.
    s = make_sample([[1, 0], [1, 0], [0, 1], [1, 0], [0, 0]], areas=[10.0, 20.0])
    f = torch.tensor(
        [[1.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 0.1], [0.3, 0.3]], dtype=torch.float64
    )
    return f, s


def test_pair_weights_of_the_case_are_as_computed_by_hand():
    f, s = _case()
    W = pair_stats(f, s).W
    assert W[0, 1] == pytest.approx(10.0) and W[0, 2] == pytest.approx(4.0)
    assert W[2, 2] == pytest.approx(1.0)


def test_hard_selects_only_individually_violating_pairs():
    f, s = _case()
    ps = pair_stats(f, s)
    pos, neg = hard_pairs(ps)
    # valid pixels 0..3. cos: (0,1)=0 (pos, < .75: yes), (0,3)=.995 (pos: no),
    # (1,3)=.0995 (pos: yes), (0,2)=1 (neg, > .5: yes), (1,2)=0 (neg: no), (2,3)=.995 (neg: yes)
    assert pos.nonzero().tolist() == [[0, 1], [1, 3]]
    assert neg.nonzero().tolist() == [[0, 2], [2, 3]]


def test_hard_loss_hand_computed():
    f, s = _case()
    f.requires_grad_(True)
    loss, stats = hard_mining_loss(f, s)
    c13 = 0.1 / math.sqrt(1.01)
    c23 = 1.0 / math.sqrt(1.01)
    l_pos = -(10.0 * 0.0 + 10.0 * c13) / 2
    l_neg = (4.0 * 1.0 + 4.0 * c23) / 2
    mean_norm = (3.0 + math.sqrt(1.01) + math.sqrt(0.18)) / 5  # pixel 4 counts in the regulariser
    reg = (1.0 - mean_norm) ** 2
    assert stats["n_pos"] == 2 and stats["n_neg"] == 2 and stats["n_valid"] == 4
    assert stats["loss_pos"] == pytest.approx(l_pos, abs=1e-9)
    assert stats["loss_neg"] == pytest.approx(l_neg, abs=1e-9)
    assert float(loss.detach()) == pytest.approx(l_pos + l_neg + reg, abs=1e-9)
    assert float(HardMining()(f, s)[0].detach()) == pytest.approx(float(loss.detach()))


def test_hard_loss_without_violations_is_only_the_regulariser():
    s = make_sample([[1, 0], [1, 0], [0, 1]])
    f = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]], dtype=torch.float64, requires_grad=True)
    loss, stats = hard_mining_loss(f, s)
    assert stats["n_pos"] == 0 and stats["n_neg"] == 0
    assert float(loss.detach()) == pytest.approx(0.0, abs=1e-12)
    loss.backward()
    assert torch.isfinite(f.grad).all()


def test_all_selects_every_positive_and_negative_pair():
    f, s = _case()
    loss, stats = AllMining()(f, s)
    # 4 valid pixels: positive pairs (0,1),(0,3),(1,3); negative (0,2),(1,2),(2,3).
    assert stats["n_pos"] == 3 and stats["n_neg"] == 3
    c13, c03, c23 = 0.1 / math.sqrt(1.01), 1.0 / math.sqrt(1.01), 1.0 / math.sqrt(1.01)
    # Z (column anchors, public code): upper pairs (i<j) whose j is an anchor of that kind.
    # Every valid pixel has a positive partner except pixel 2 -> columns 1, 3: 1 + 3 = 4 pairs.
    # Every valid pixel has a negative partner -> all 6 upper pairs.
    l_pos = -(10.0 * 0.0 + 10.0 * c03 + 10.0 * c13) / 4
    l_neg = (4.0 * 1.0 + 4.0 * 0.0 + 4.0 * c23) / 6
    assert stats["loss_pos"] == pytest.approx(l_pos, abs=1e-9)
    assert stats["loss_neg"] == pytest.approx(l_neg, abs=1e-9)
    assert float(all_mining_loss(f, s)[0].detach()) == pytest.approx(float(loss.detach()))


def test_hard_all_soft_differ_on_the_same_input():
    f, s = _case()
    soft = SoftMining()(f, s)[1]
    hard = HardMining()(f, s)[1]
    every = AllMining()(f, s)[1]
    assert (hard["n_pos"], every["n_pos"]) == (2, 3)
    assert hard["n_pos"] <= soft["n_pos"] <= every["n_pos"]
    assert hard["n_neg"] <= soft["n_neg"] <= every["n_neg"]


def test_bad_thresholds_and_options_fail_clearly():
    with pytest.raises(ObjectiveInputError, match="tau_pos must be a cosine"):
        HardMining(tau_pos=1.5)
    with pytest.raises(ValueError, match="anchor_side"):
        get_objective("trase-all", anchor_side="diagonal")
