"""The soft (Jaccard) correspondence of TRASE's objective against hand-computed values."""

import pytest
import torch

from baselines.all_mining import AllMining
from tests.trase.objectives.test_soft import _sample
from trase.objectives.base import mask_jaccard, pair_stats
from trase.objectives.soft import SoftMining


def test_jaccard_values_by_hand():
    # pixel 0: masks {a, b}; pixel 1: {b}; pixel 2: {c}; pixel 3: {a, b}
    m = torch.tensor([[1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]], dtype=torch.bool)
    expected = torch.tensor([
        [1.0, 0.5, 0.0, 1.0],
        [0.5, 1.0, 0.0, 0.5],
        [0.0, 0.0, 1.0, 0.0],
        [1.0, 0.5, 0.0, 1.0],
    ])
    assert torch.equal(mask_jaccard(m), expected)


@pytest.mark.parametrize("objective", [SoftMining, AllMining])
def test_disjoint_masks_give_the_binary_loss(objective):
    # every pair shares all or none of its masks: C in {0, 1}, so both rules are one loss
    torch.manual_seed(0)
    s = _sample([[1, 0, 0]] * 4 + [[0, 1, 0]] * 3 + [[0, 0, 1]] * 3 + [[0, 0, 0]], areas=[4.0, 3.0, 30.0])
    f = torch.randn(11, 8)
    f1, f2 = f.clone().requires_grad_(True), f.clone().requires_grad_(True)
    loss1, stats1 = objective(impl="reference")(f1, s)
    loss2, stats2 = objective(correspondence="jaccard", impl="reference")(f2, s)
    loss1.backward()
    loss2.backward()
    assert stats1 == pytest.approx(stats2)
    torch.testing.assert_close(f1.grad, f2.grad)


def test_a_shared_large_mask_pulls_half_and_pushes_half():
    # pixels 0, 1: a small object (mask a) inside a large mask b; pixel 2: only in b.
    # Features: 0, 1 equal; 2 near them (the large mask merged them).
    s = _sample([[1, 1], [1, 1], [0, 1]], areas=[2.0, 3.0])
    f = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.9, 0.1]], requires_grad=True)
    _, stats_b = SoftMining(impl="reference")(f, s)
    assert stats_b["n_neg"] == 0 and stats_b["loss_neg"] == 0.0  # binary: all three are one object
    assert stats_b["n_pos"] == 0  # and every positive is perfect (C_F >= tau_pos)
    loss_j, stats_j = SoftMining(correspondence="jaccard")(f, s)
    ps = pair_stats(f, s)
    # pairs (0, 2) and (1, 2) have C = 1/2: negatives with weight W / 2, C_F > tau_neg;
    # the negative anchors are 0, 1 and 2, so Z_neg counts the column-anchored pairs (0,1), (0,2), (1,2)
    expected_neg = (ps.W[0, 2] * 0.5 * ps.CF[0, 2] + ps.W[1, 2] * 0.5 * ps.CF[1, 2]) / 3
    assert stats_j["loss_neg"] == pytest.approx(float(expected_neg), rel=1e-6)
    assert stats_j["n_neg"] == 2
    loss_j.backward()
    assert torch.isfinite(f.grad).all() and f.grad.abs().sum() > 0


def test_an_imperfect_positive_with_a_shared_large_mask_pulls_by_half():
    # pixels 0 and 1 share the large mask b only (C = 1/2) and are orthogonal: an imperfect
    # positive weighted W / 2; pixel 2 shares both of pixel 0's masks (C = 1)
    s = _sample([[1, 1], [0, 1], [1, 1]], areas=[2.0, 3.0])
    f = torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]], requires_grad=True)
    _, stats = SoftMining(correspondence="jaccard", impl="reference")(f, s)
    ps = pair_stats(f, s)
    # positive anchors (column side): 1 (partner 0, C_F 0) -> pair (0, 1); 2's only imperfect
    # positive partner is 1 -> pairs (0, 2), (1, 2); Z_pos = 1 + 2
    expected = -(ps.W[0, 1] * 0.5 * ps.CF[0, 1] + ps.W[0, 2] * 1.0 * ps.CF[0, 2] + ps.W[1, 2] * 0.5 * ps.CF[1, 2]) / 3
    assert stats["loss_pos"] == pytest.approx(float(expected), rel=1e-6)
    assert stats["n_pos"] == 3
    _, fused = SoftMining(correspondence="jaccard", impl="fused")(f.detach().clone(), s)
    assert fused == pytest.approx(stats)


def test_jaccard_on_degenerate_inputs_is_finite():
    obj = SoftMining(correspondence="jaccard")
    for s, f in [(_sample([[1]] * 4), torch.randn(4, 3)), (_sample([[0], [0]]), torch.randn(2, 3)),
                 (_sample([[1, 1], [0, 1]]), torch.zeros(2, 3))]:
        f = f.clone().requires_grad_(True)
        loss, _ = obj(f, s)
        loss.backward()
        assert torch.isfinite(loss) and torch.isfinite(f.grad).all()


def test_bad_correspondence_options_fail():
    with pytest.raises(ValueError, match="correspondence must be one of"):
        SoftMining(correspondence="soft")
    from trase.objectives.fused import fused_pair_losses

    s = _sample([[1, 1], [0, 1]])
    # hard mining's kernels keep one selection bit per pair: a soft pair can be both kinds
    with pytest.raises(ValueError, match="'binary' for hard mining"):
        fused_pair_losses(torch.randn(2, 3), s, hard=True, tau_pos=0.75, tau_neg=0.5, correspondence="jaccard")
