import pytest
import torch

from trase.objectives import get_objective
from trase.objectives.base import PixelSample, pair_stats
from trase.objectives.soft import SoftMining, all_anchors, select_pairs, soft_anchors


def _sample(membership, areas=None):
    m = torch.tensor(membership, dtype=torch.bool)
    n, k = m.shape
    area = torch.tensor(areas if areas is not None else [10.0] * k)
    mean_area = torch.stack([area[row].mean() if row.any() else torch.tensor(0.0) for row in m])
    return PixelSample(torch.arange(n), m, area, mean_area)


def _check_finite(loss, f):
    loss.backward()
    assert torch.isfinite(loss)
    assert torch.isfinite(f.grad).all()


def test_registered_by_name():
    obj = get_objective("trase")
    assert isinstance(obj, SoftMining) and obj.name == "trase"


def test_hand_computed_selection_and_loss():
    # pixels 0,1 in mask A; pixel 2 in mask B. Features: 0 and 1 orthogonal (bad positive),
    # 2 equal to 0 (bad negative pair 0-2), 1-2 orthogonal (good negative).
    s = _sample([[1, 0], [1, 0], [0, 1]])
    f = torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]], requires_grad=True)
    ps = pair_stats(f, s)
    pos_a, neg_a = soft_anchors(ps)
    assert pos_a.tolist() == [True, True, False]
    assert neg_a.tolist() == [True, False, True]
    pos, neg, pos_c, neg_c = select_pairs(ps, pos_a, neg_a, "column")
    # column anchors: pairs (i<j) with j anchor. pos candidates: (0,1); neg candidates: (0,2),(1,2)
    assert pos.nonzero().tolist() == [[0, 1]]
    assert neg.nonzero().tolist() == [[0, 2], [1, 2]]
    assert int(pos_c.sum()) == 1 and int(neg_c.sum()) == 2
    loss, stats = SoftMining()(f, s)
    W = ps.W
    expected_pos = -(W[0, 1] * 0.0) / 1
    expected_neg = (W[0, 2] * 1.0 + W[1, 2] * 0.0) / 2
    assert stats["loss_pos"] == pytest.approx(float(expected_pos), abs=1e-6)
    assert stats["loss_neg"] == pytest.approx(float(expected_neg), abs=1e-6)
    assert stats["reg"] == pytest.approx(0.0, abs=1e-6)
    assert stats["n_pos"] == 1 and stats["n_neg"] == 2
    _check_finite(loss, f)


def test_row_side_differs_from_column():
    s = _sample([[1, 0], [1, 0], [0, 1]])
    f = torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    ps = pair_stats(f, s)
    pos_a, neg_a = soft_anchors(ps)
    _, neg_row, _, _ = select_pairs(ps, pos_a, neg_a, "row")
    # row: pairs (i<j) with i anchor: neg anchors are 0 and 2 -> (0,2) only (0,1) is positive
    assert neg_row.nonzero().tolist() == [[0, 2]]


def test_perfect_features_give_zero_contrastive_loss():
    s = _sample([[1, 0], [1, 0], [0, 1], [0, 1]])
    f = torch.tensor([[1.0, 0], [1.0, 0], [0, 1.0], [0, 1.0]], requires_grad=True)
    loss, stats = SoftMining()(f, s)
    assert stats["n_pos"] == 0 and stats["n_neg"] == 0
    assert loss.item() == pytest.approx(0.0, abs=1e-6)


def test_all_anchors_cover_everything():
    s = _sample([[1, 0], [1, 0], [0, 1]])
    ps = pair_stats(torch.randn(3, 4), s)
    pos, neg = all_anchors(ps)
    assert pos.tolist() == [True, True, False] and neg.all()


def test_gradient_moves_features_the_right_way():
    torch.manual_seed(0)
    s = _sample([[1, 0]] * 5 + [[0, 1]] * 5)
    f = torch.randn(10, 8, requires_grad=True)
    opt = torch.optim.Adam([f], lr=0.05)
    obj = SoftMining()
    for _ in range(200):
        opt.zero_grad()
        loss, _ = obj(f, s)
        loss.backward()
        opt.step()
    ps = pair_stats(f.detach(), s)
    assert ps.CF[:5, :5].min() > 0.75 and ps.CF[:5, 5:].max() < 0.5


@pytest.mark.parametrize("side", ["column", "row", "either"])
@pytest.mark.parametrize("normalise", ["anchor_pairs", "selected"])
def test_degenerate_inputs_are_finite(side, normalise):
    obj = SoftMining(anchor_side=side, normalise=normalise)
    cases = [
        (_sample([[1]] * 6), torch.randn(6, 4)),  # all pixels in one mask: no negatives
        (_sample([[1, 0, 0], [0, 1, 0], [0, 0, 1]]), torch.randn(3, 4)),  # no positives
        (_sample([[1, 0]] * 3 + [[0, 1]] * 3), torch.zeros(6, 4)),  # zero-norm features
        (_sample([[1]]), torch.randn(1, 4)),  # a single pixel
        (_sample([[0], [0]]), torch.randn(2, 4)),  # no pixel in a sampled mask
        (PixelSample(torch.zeros(0, dtype=torch.long), torch.zeros(0, 0, dtype=torch.bool),
                     torch.zeros(0), torch.zeros(0)), torch.zeros(0, 4)),  # empty view
    ]
    for s, f in cases:
        f = f.clone().requires_grad_(True)
        loss, stats = obj(f, s)
        _check_finite(loss, f)
        assert all(torch.isfinite(torch.tensor(float(v))) for v in stats.values())


def test_bad_options_fail():
    with pytest.raises(ValueError, match="anchor_side"):
        SoftMining(anchor_side="diag")
    with pytest.raises(ValueError, match="normalise"):
        SoftMining(normalise="mean")


def test_fast_pair_weights_match_reference():
    from trase.objectives.base import pair_weights, pair_weights_reference

    g = torch.Generator().manual_seed(0)
    for s in [torch.rand(50, generator=g) * 1000, torch.tensor([0.0, 5.0, 5.0, 0.0, 20.0]),
              torch.zeros(4), torch.full((3,), 7.0), torch.zeros(0), torch.tensor([3.0])]:
        torch.testing.assert_close(pair_weights(s), pair_weights_reference(s), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("side", ["column", "row", "either"])
def test_anchor_pair_count_matches_matrix(side):
    from trase.objectives.soft import anchor_pair_count, anchor_pairs

    g = torch.Generator().manual_seed(1)
    for V in (0, 1, 2, 7, 30):
        a = torch.rand(V, generator=g) < 0.4
        upper = torch.ones(V, V, dtype=torch.bool).triu(1)
        assert anchor_pair_count(a, side) == int(anchor_pairs(a, upper, side).sum())
