"""The fused pair kernels (trase.objectives.fused) against the dense torch reference."""

import math

import numpy as np
import pytest
import torch

from baselines.all_mining import AllMining
from baselines.hard_mining import HardMining
from trase.objectives.base import PixelSample, pair_weights
from trase.objectives.fused import fused_pair_losses, pack_membership, weight_factors
from trase.objectives.soft import SoftMining


def _sample(n, m, p=0.15, seed=0, zero_area=0.1):
    g = torch.Generator().manual_seed(seed)
    member = torch.rand(n, m, generator=g) < p
    mean_area = torch.rand(n, generator=g) * 500 + 1
    mean_area[torch.rand(n, generator=g) < zero_area] = 0.0  # W = 1 rows/columns
    return PixelSample(torch.arange(n), member, member.sum(0).float() + 1, mean_area)


def _features(n, d, dtype, seed=1):
    g = torch.Generator().manual_seed(seed)
    f = torch.randn(n, d, generator=g, dtype=dtype)
    # some near-duplicates so that imperfect negatives exist, and a zero-norm feature
    f[1::7] = f[0] + 0.05 * torch.randn(f[1::7].shape, generator=g, dtype=dtype)
    f[min(3, n - 1)] = 0.0
    return f


def _run(obj, f, s):
    """-> (loss, stats, d loss / d features)."""
    x = f.clone().requires_grad_(True)
    loss, stats = obj(x, s)
    loss.backward()
    return float(loss.detach()), stats, x.grad


OBJECTIVES = [
    ("soft column", lambda impl: SoftMining(impl=impl)),
    ("soft row", lambda impl: SoftMining(anchor_side="row", impl=impl)),
    ("soft either", lambda impl: SoftMining(anchor_side="either", impl=impl)),
    ("soft selected", lambda impl: SoftMining(normalise="selected", impl=impl)),
    ("soft either selected", lambda impl: SoftMining(anchor_side="either", normalise="selected", impl=impl)),
    ("soft other taus", lambda impl: SoftMining(tau_pos=0.3, tau_neg=-0.2, impl=impl)),
    ("all", lambda impl: AllMining(impl=impl)),
    ("all row", lambda impl: AllMining(anchor_side="row", impl=impl)),
    ("hard", lambda impl: HardMining(impl=impl)),
    ("hard negative tau", lambda impl: HardMining(tau_pos=0.2, tau_neg=-0.3, impl=impl)),
]


# the soft correspondence: pixels in several masks give C strictly between 0 and 1
JACCARD = [
    ("jaccard column", lambda impl: SoftMining(correspondence="jaccard", impl=impl)),
    ("jaccard row", lambda impl: SoftMining(anchor_side="row", correspondence="jaccard", impl=impl)),
    ("jaccard either selected", lambda impl: SoftMining(anchor_side="either", normalise="selected",
                                                        correspondence="jaccard", impl=impl)),
    ("jaccard all", lambda impl: AllMining(correspondence="jaccard", impl=impl)),
]


def _compare(make, f, s, rtol):
    lf, sf, gf = _run(make("fused"), f, s)
    lr, sr, gr = _run(make("reference"), f, s)
    assert sf["n_pos"] == sr["n_pos"] and sf["n_neg"] == sr["n_neg"] and sf["n_valid"] == sr["n_valid"]
    for key in ("loss_pos", "loss_neg", "reg"):
        assert sf[key] == pytest.approx(sr[key], rel=rtol, abs=1e-7), key
    assert lf == pytest.approx(lr, rel=rtol, abs=1e-7)
    assert torch.isfinite(gf).all()
    assert gf.shape == gr.shape
    if gr.numel():
        scale = float(gr.abs().max()) + 1e-30
        assert float((gf - gr).abs().max()) <= rtol * scale, float((gf - gr).abs().max()) / scale


@pytest.mark.parametrize("name,make", OBJECTIVES, ids=[o[0] for o in OBJECTIVES])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_fused_matches_reference(name, make, dtype):
    # n = 150 spans several kernel blocks only with tiny blocks; M = 6 (one word)
    s = _sample(150, 6)
    f = _features(150, 8, dtype)
    _compare(make, f, s, rtol=1e-9 if dtype == torch.float64 else 1e-5)


@pytest.mark.parametrize("name,make", JACCARD, ids=[o[0] for o in JACCARD])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_fused_jaccard_matches_reference(name, make, dtype):
    s = _sample(150, 6, p=0.4)
    assert ((s.membership.sum(1) > 1).sum()) > 50  # many pixels in several masks
    f = _features(150, 8, dtype)
    _compare(make, f, s, rtol=1e-9 if dtype == torch.float64 else 1e-5)


@pytest.mark.parametrize("name,make", OBJECTIVES[:1] + OBJECTIVES[-3:] + JACCARD[:1],
                         ids=["soft", "all", "all row", "hard", "jaccard"])
def test_fused_matches_reference_many_masks_and_blocks(name, make, monkeypatch):
    from trase.objectives import fused

    monkeypatch.setattr(fused, "BLOCK_BYTES", 1)  # blocks of 32 rows: many blocks, a ragged last one
    s = _sample(101, 150, p=0.03)  # 150 masks: 3 membership words
    f = _features(101, 5, torch.float64)
    _compare(make, f, s, rtol=1e-9)


@pytest.mark.parametrize("correspondence", ["binary", "jaccard"])
def test_two_threads_match_one(monkeypatch, correspondence):
    from trase.objectives import fused

    monkeypatch.setattr(fused, "PARALLEL_MIN_PIXELS", 0)  # the parallel driver even for 300 pixels
    monkeypatch.setattr(fused, "BLOCK_BYTES", 1)  # several blocks, rows split over 2 threads each
    s = _sample(300, 25)
    f = _features(300, 16, torch.float32)
    old = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = _run(SoftMining(impl="fused", correspondence=correspondence), f, s)
        torch.set_num_threads(2)
        two = _run(SoftMining(impl="fused", correspondence=correspondence), f, s)
        assert torch.get_num_threads() == 2  # numba's thread setting did not leak into torch
    finally:
        torch.set_num_threads(old)
    assert one[1]["n_pos"] == two[1]["n_pos"] and one[1]["n_neg"] == two[1]["n_neg"]
    assert one[0] == pytest.approx(two[0], rel=1e-6)
    torch.testing.assert_close(one[2], two[2], rtol=1e-5, atol=1e-7)


def test_separate_term_gradients_match_reference():
    """g_pos != g_neg: the backward uses each term's incoming gradient."""
    from trase.objectives.base import pair_stats
    from trase.objectives.soft import (
        anchor_pair_count,
        select_pairs,
        soft_anchors,
        weighted_pair_losses,
    )

    s = _sample(80, 5)
    f = _features(80, 6, torch.float64)
    x = f.clone().requires_grad_(True)
    lp, ln, n_pos, n_neg, _ = fused_pair_losses(x, s, tau_pos=0.75, tau_neg=0.5)
    (2.5 * lp - 0.7 * ln).backward()
    y = f.clone().requires_grad_(True)
    ps = pair_stats(y, s)
    pa, na = soft_anchors(ps)
    pos, neg, _, _ = select_pairs(ps, pa, na)
    rp, rn = weighted_pair_losses(ps, pos, neg, anchor_pair_count(pa), anchor_pair_count(na))
    (2.5 * rp - 0.7 * rn).backward()
    assert n_pos == int(pos.sum()) and n_neg == int(neg.sum())
    assert lp.item() == pytest.approx(rp.item(), rel=1e-9) and ln.item() == pytest.approx(rn.item(), rel=1e-9)
    torch.testing.assert_close(x.grad, y.grad, rtol=1e-9, atol=1e-12)


def _empty_sample():
    return PixelSample(torch.zeros(0, dtype=torch.long), torch.zeros(0, 0, dtype=torch.bool),
                       torch.zeros(0), torch.zeros(0))


def _hand(member, areas=None):
    m = torch.tensor(member, dtype=torch.bool)
    area = torch.tensor(areas if areas is not None else [10.0] * m.shape[1])
    mean_area = torch.stack([area[row].mean() if row.any() else torch.tensor(0.0) for row in m])
    return PixelSample(torch.arange(m.shape[0]), m, area, mean_area)


DEGENERATE = [
    ("all in one mask", _hand([[1]] * 6), torch.randn(6, 4)),
    ("no positives", _hand([[1, 0, 0], [0, 1, 0], [0, 0, 1]]), torch.randn(3, 4)),
    ("zero-norm features", _hand([[1, 0]] * 3 + [[0, 1]] * 3), torch.zeros(6, 4)),
    ("single pixel", _hand([[1]]), torch.randn(1, 4)),
    ("two pixels", _hand([[1], [0], [1]]), torch.randn(3, 4)),
    ("no pixel in a sampled mask", _hand([[0], [0]]), torch.randn(2, 4)),
    ("no sampled masks", PixelSample(torch.arange(3), torch.zeros(3, 0, dtype=torch.bool), torch.zeros(0),
                                     torch.zeros(3)), torch.randn(3, 4)),
    ("equal areas (W = 1)", _hand([[1, 0], [1, 0], [0, 1], [1, 1]]), torch.randn(4, 4)),
    ("empty view", _empty_sample(), torch.zeros(0, 4)),
]


@pytest.mark.parametrize("name,s,f", DEGENERATE, ids=[d[0] for d in DEGENERATE])
@pytest.mark.parametrize("which", ["soft", "soft either", "all", "hard", "jaccard", "jaccard either"])
def test_degenerate_inputs_match_reference_and_are_finite(name, s, f, which):
    make = {"soft": OBJECTIVES[0][1], "soft either": OBJECTIVES[2][1], "all": OBJECTIVES[6][1],
            "hard": OBJECTIVES[8][1], "jaccard": JACCARD[0][1], "jaccard either": JACCARD[2][1]}[which]
    _compare(make, f.double(), s, rtol=1e-9)


def test_no_grad_and_repeated_backward():
    s = _sample(40, 4)
    f = _features(40, 3, torch.float32)
    with torch.no_grad():
        loss, _ = SoftMining(impl="fused")(f, s)
    assert torch.isfinite(loss)
    x = f.clone().requires_grad_(True)
    loss, _ = SoftMining(impl="fused")(x, s)
    loss.backward(retain_graph=True)
    g1 = x.grad.clone()
    loss.backward()
    torch.testing.assert_close(x.grad, 2 * g1)


def test_pack_membership_and_weight_factors():
    g = np.random.default_rng(0)
    member = g.random((37, 130)) < 0.1
    bits = pack_membership(member)
    assert bits.shape == (3, 37) and bits.dtype == np.uint64
    C = ((bits[:, :, None] & bits[:, None, :]) != 0).any(axis=0)
    np.testing.assert_array_equal(C, (member.astype(int) @ member.T.astype(int)) > 0)
    assert pack_membership(np.zeros((4, 0), bool)).shape == (1, 4)
    for s in (torch.rand(20, generator=torch.Generator().manual_seed(0)) * 100, torch.tensor([0.0, 5.0, 5.0, 0.0, 20.0]),
              torch.zeros(3), torch.full((3,), 7.0)):
        b, k = weight_factors(s)
        p = np.outer(b, b)
        W = np.where(p > 0, 1 + k * (p - 1), 1.0)
        np.testing.assert_allclose(W, pair_weights(s).numpy(), rtol=1e-6)


def test_bad_impl_and_side_fail():
    with pytest.raises(ValueError, match="impl"):
        SoftMining(impl="gpu")
    with pytest.raises(ValueError, match="impl"):
        HardMining(impl="dense")
    with pytest.raises(ValueError, match="anchor side"):
        fused_pair_losses(torch.zeros(2, 3), _hand([[1], [1]]), tau_pos=0.75, tau_neg=0.5, side="diag")
    assert math.isinf(AllMining().thresholds()[0])
    half = torch.randn(3, 4).half()
    with pytest.raises(ValueError, match="float32/float64"):
        SoftMining(impl="fused")(half, _hand([[1], [1], [0]]))


def test_auto_uses_the_reference_for_other_dtypes(monkeypatch):
    from trase.objectives import soft

    def boom(*a, **k):
        raise AssertionError("fused called")

    monkeypatch.setattr(soft, "fused_pair_losses", boom)
    s = _hand([[1, 0], [1, 0], [0, 1]])
    loss, stats = SoftMining()(torch.randn(3, 4).bfloat16(), s)  # auto -> reference
    assert torch.isfinite(loss.float()) and stats["n_valid"] == 3
    with pytest.raises(AssertionError, match="fused called"):
        SoftMining()(torch.randn(3, 4), s)  # auto on CPU float32 -> fused
