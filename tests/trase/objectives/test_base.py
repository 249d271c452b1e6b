import pytest
import torch

from trase.objectives.base import (
    ObjectiveInputError,
    PixelSample,
    norm_regulariser,
    pair_stats,
    pair_weights,
)


def _sample(membership, areas=None):
    m = torch.tensor(membership, dtype=torch.bool)
    n, k = m.shape
    area = torch.tensor(areas if areas is not None else [10.0] * k)
    mean_area = torch.stack([area[row].mean() if row.any() else torch.tensor(0.0) for row in m])
    return PixelSample(torch.arange(n), m, area, mean_area)


def test_pair_stats_drops_pixels_in_no_sampled_mask():
    s = _sample([[1, 0], [1, 1], [0, 1], [0, 0]])
    f = torch.tensor([[1.0, 0.0], [1.0, 1.0], [0.0, 2.0], [5.0, 5.0]])
    ps = pair_stats(f, s)
    assert ps.valid.tolist() == [True, True, True, False]
    assert ps.C.tolist() == [[True, True, False], [True, True, True], [False, True, True]]
    assert ps.CF[0, 1].item() == pytest.approx(2**-0.5)
    assert ps.CF[0, 2].item() == pytest.approx(0.0)
    assert ps.upper.tolist() == [[False, True, True], [False, False, True], [False, False, False]]


def test_pair_weights_hand_computed():
    # areas 1, 2, 0: S = [[1,2,0],[2,4,0],[0,0,0]]; max 4; W = 4/S -> [[4,2,1],[2,1,1],[1,1,1]]
    W = pair_weights(torch.tensor([1.0, 2.0, 0.0]))
    expected = 1 + 9 * (torch.tensor([[4.0, 2, 1], [2, 1, 1], [1, 1, 1]]) - 1) / 3
    torch.testing.assert_close(W, expected)
    assert torch.equal(pair_weights(torch.tensor([3.0, 3.0])), torch.ones(2, 2))


def test_zero_features_are_finite():
    s = _sample([[1], [1]])
    f = torch.zeros(2, 4, requires_grad=True)
    ps = pair_stats(f, s)
    loss = ps.CF.sum() + norm_regulariser(f)
    loss.backward()
    assert torch.isfinite(ps.CF).all() and torch.isfinite(f.grad).all()


def test_bad_shapes_fail_clearly():
    with pytest.raises(ObjectiveInputError, match="membership must be"):
        PixelSample(torch.arange(3), torch.ones(2, 1, dtype=torch.bool), torch.ones(1), torch.ones(3))
    s = _sample([[1], [1]])
    with pytest.raises(ObjectiveInputError, match=r"features must be \[Np=2, D\]"):
        pair_stats(torch.zeros(3, 4), s)


@pytest.mark.parametrize("soft", [False, True], ids=["binary C", "soft C"])
def test_fused_pair_losses_match_reference_values_and_gradients(soft):
    from trase.objectives.soft import (
        select_pairs,
        soft_anchors,
        weighted_pair_losses,
        weighted_pair_losses_reference,
    )

    g = torch.Generator().manual_seed(0)
    n = 60
    member = torch.rand(n, 6, generator=g) < 0.3
    s = PixelSample(torch.arange(n), member, member.sum(0).double() + 1, torch.rand(n, generator=g, dtype=torch.float64) * 50)
    f = torch.randn(n, 8, generator=g, dtype=torch.float64)
    f[3] = 0.0  # a zero feature
    grads = []
    for fn in (weighted_pair_losses, weighted_pair_losses_reference):
        x = f.clone().requires_grad_(True)
        ps = pair_stats(x, s, "jaccard" if soft else "binary")
        pa, na = soft_anchors(ps)
        pos, neg, pc, nc = select_pairs(ps, pa, na)
        if soft:  # C strictly between 0 and 1 somewhere: weights W C and W (1 - C)
            assert ((ps.share > 0) & (ps.share < 1)).any()
        lp, ln = fn(ps, pos, neg, pc.sum(), nc.sum())
        (lp + ln).backward()
        grads.append((lp.item(), ln.item(), x.grad.clone()))
    assert grads[0][0] == pytest.approx(grads[1][0], abs=1e-12)
    assert grads[0][1] == pytest.approx(grads[1][1], abs=1e-12)
    torch.testing.assert_close(grads[0][2], grads[1][2], atol=1e-12, rtol=1e-10)
