"""SAGA's scale gate, correspondence targets, pair weights, mining and loss, each against a plain
reference written here from the public code's description (loops, no vectorisation)."""

import math

import numpy as np
import pytest
import torch
from trase_bench_saga.objective import (
    MAX_PAIR_WEIGHT,
    ScaleGate,
    gate_from_dict,
    mined_pairs,
    pair_weights,
    saga_loss,
    scale_targets,
)
from trase_bench_saga.scales import QuantileMap, eroded, mask_scale
from trase_bench_saga.train import draw_scales


def test_scale_gate_is_a_sigmoid_of_a_linear_map_and_round_trips():
    g = ScaleGate(6, torch.Generator().manual_seed(3))
    q = torch.tensor([0.0, 0.25, 1.0])
    out = g(q)
    assert out.shape == (3, 6) and bool((out > 0).all()) and bool((out < 1).all())
    w, b = g.linear.weight.detach()[:, 0], g.linear.bias.detach()
    for i, s in enumerate(q):
        ref = [1.0 / (1.0 + math.exp(-(float(w[c]) * float(s) + float(b[c])))) for c in range(6)]
        assert np.allclose(out[i].detach().numpy(), ref, atol=1e-6)
        assert np.allclose(gate_from_dict(g.to_dict(), float(s)), ref, atol=1e-6)
    same = ScaleGate(6, torch.Generator().manual_seed(3))
    assert torch.equal(same.linear.weight, g.linear.weight)  # the generator decides the init


def _targets_reference(member, index):
    """The public code's loop: masks 0..index (largest first) made exclusive from the smallest
    up, the smaller masks as they are; a pair corresponds where one row holds both."""
    M, P = member.shape
    if index < 0:
        rows = [list(member[m]) for m in range(M)]
    else:
        rows = [[False] * P for _ in range(M)]
        for j in range(index, -1, -1):
            for p in range(P):
                rows[j][p] = bool(member[j, p]) and not any(rows[k][p] for k in range(j + 1, index + 1))
        for j in range(index + 1, M):
            rows[j] = list(member[j])
    out = np.zeros((P, P), np.float32)
    for a in range(P):
        for b in range(P):
            out[a, b] = float(any(rows[m][a] and rows[m][b] for m in range(M)))
    return out


def test_scale_targets_match_the_reference():
    rng = np.random.default_rng(0)
    member = rng.random((5, 9)) < 0.45
    member[0] = True  # the largest mask covers everything
    for index in (-1, 0, 1, 2, 4):
        got = scale_targets(torch.from_numpy(member), index).numpy()
        assert np.array_equal(got, _targets_reference(member, index)), index
    # nested masks: at the big scale the two halves correspond, at the small one they do not
    nested = np.array([[1, 1, 1, 1], [1, 1, 0, 0], [0, 0, 1, 1]], bool)
    assert scale_targets(torch.from_numpy(nested), 0)[0, 3] == 1
    assert scale_targets(torch.from_numpy(nested), 2)[0, 3] == 0
    assert scale_targets(torch.from_numpy(nested), 2)[0, 1] == 1


def test_pair_weights_span_one_to_ten():
    area = torch.tensor([10.0, 100.0, 1000.0])
    w = pair_weights(area).numpy()
    prod = np.outer(area.numpy(), area.numpy())
    raw = np.maximum(prod.max() / prod, 1.0)
    ref = (raw - raw.min()) / (raw.max() - raw.min()) * (MAX_PAIR_WEIGHT - 1) + 1
    assert np.allclose(w, ref, atol=1e-5) and w.min() == pytest.approx(1.0) and w.max() == pytest.approx(10.0)
    assert np.all(pair_weights(torch.tensor([5.0, 5.0])).numpy() == 1.0)  # equal areas: no stretch


def _loss_reference(rendered, gates, targets, weights, rand, hi=0.75, lo=0.5):
    S, P = targets.shape[0], targets.shape[1]
    f = rendered[None] * gates[:, None, :]
    f = f / np.linalg.norm(f, axis=-1, keepdims=True)
    corr = np.einsum("spd,sqd->spq", f, f)
    votes = targets.sum(0)
    always, never = votes == S, votes == 0
    differ = ~(always | never)
    half = differ.sum() / 2
    pos_pairs, neg_pairs = [], []
    for a in range(P):
        for b in range(a + 1, P):
            wrong_pos = any(corr[s, a, b] < hi and targets[s, a, b] == 1 for s in range(S))
            wrong_neg = any(corr[s, a, b] > lo and targets[s, a, b] == 0 for s in range(S))
            if differ[a, b] or wrong_pos or (always[a, b] and rand[a, b] < half / always.sum()):
                pos_pairs.append((a, b))
            if differ[a, b] or wrong_neg or (never[a, b] and rand[a, b] < half / max(never.sum(), 1e-300)):
                neg_pairs.append((a, b))
    pull = -np.mean([weights[a, b] * targets[s, a, b] * corr[s, a, b] for s in range(S) for a, b in pos_pairs])
    push = np.mean([weights[a, b] * (1 - targets[s, a, b]) * max(corr[s, a, b], 0.0)
                    for s in range(S) for a, b in neg_pairs])
    return pull + push, len(pos_pairs), len(neg_pairs)


def test_loss_matches_the_reference_on_a_tiny_example():
    rng = np.random.default_rng(1)
    P, D = 7, 4
    member = rng.random((4, P)) < 0.5
    member[0] = True
    targets = np.stack([scale_targets(torch.from_numpy(member), i).numpy() for i in (-1, 1, 3)])
    rendered = rng.normal(size=(P, D))
    gates = rng.random((3, D))
    weights = pair_weights(torch.from_numpy(rng.random(P) * 50 + 1)).numpy().astype(np.float64)
    rand = rng.random((P, P))
    loss, stats = saga_loss(torch.from_numpy(rendered), torch.from_numpy(gates), torch.from_numpy(targets).double(),
                            torch.from_numpy(weights), torch.from_numpy(rand))
    ref, n_pos, n_neg = _loss_reference(rendered, gates, targets, weights, rand)
    assert float(loss) == pytest.approx(ref, rel=1e-9, abs=1e-12)
    assert (stats["pos_pairs"], stats["neg_pairs"]) == (n_pos, n_neg)


def test_mining_keeps_pairs_that_differ_between_scales():
    targets = torch.zeros(2, 3, 3)
    targets[0, 0, 1] = targets[0, 1, 0] = 1  # pair (0, 1) corresponds at one scale only
    corr = torch.zeros(2, 3, 3)
    pos, neg = mined_pairs(corr, targets, torch.ones(3, 3))
    assert bool(pos[0, 1]) and bool(neg[0, 1]) and not bool(pos[1, 0]) and not bool(pos.diagonal().any())


def test_loss_gradient_pulls_corresponding_pixels_together():
    torch.manual_seed(0)
    rendered = torch.randn(6, 8, requires_grad=True)
    targets = torch.zeros(1, 6, 6)
    targets[0, :3, :3] = 1
    targets[0, 3:, 3:] = 1
    opt = torch.optim.Adam([rendered], lr=0.05)
    for _ in range(200):
        loss, _ = saga_loss(rendered, torch.ones(1, 8), targets, torch.ones(6, 6), torch.zeros(6, 6))
        opt.zero_grad()
        loss.backward()
        opt.step()
    f = torch.nn.functional.normalize(rendered.detach(), dim=1)
    corr = f @ f.T
    assert float(corr[0, 1]) > 0.9 and float(corr[0, 4]) < 0.1


def test_mask_scale_is_twice_the_points_spread():
    H, W = 12, 12
    rows, cols = np.mgrid[0:H, 0:W].astype(float)
    points = np.stack([cols, rows, np.zeros_like(cols)], axis=-1)  # a plane, 1 unit per pixel
    mask = np.zeros((H, W), bool)
    mask[2:10, 2:10] = True
    core = eroded(mask)
    assert core[3, 3] and not core[2, 2] and core[2, 5]  # corners lose (4 of 9), edges keep (6 of 9)
    pts = points[core]
    ref = float(np.linalg.norm(2 * pts.std(axis=0, ddof=1)))
    assert mask_scale(points, np.ones((H, W), bool), mask) == pytest.approx(ref)
    tiny = np.zeros((H, W), bool)
    tiny[5, 5:7] = True  # erosion leaves nothing: the whole mask
    assert mask_scale(points, np.ones((H, W), bool), tiny) == pytest.approx(2 * math.sqrt(0.5))
    assert mask_scale(points, np.zeros((H, W), bool), mask) == 0.0  # no surface


def test_quantile_map_matches_scikit_learn():
    sklearn = pytest.importorskip("sklearn.preprocessing")
    s = np.r_[np.random.default_rng(0).gamma(2.0, 1.0, 300), [1.0, 1.0, 1.0]]
    q = QuantileMap.fit(s)
    ref = sklearn.QuantileTransformer(output_distribution="uniform", n_quantiles=len(s)).fit(s.reshape(-1, 1))
    x = np.linspace(-1.0, 12.0, 60)
    assert np.allclose(q(x), ref.transform(x.reshape(-1, 1))[:, 0], atol=1e-12)


def test_drawn_scales_fall_below_their_mask_and_above_the_next():
    scales = np.array([5.0, 3.0, 2.0, 0.5])
    rng = np.random.default_rng(0)
    for _ in range(50):
        index, s = draw_scales(scales, upper=6.0, n_scales=2, rng=rng)
        assert index[0] == -1 and 5.0 <= s[0] <= 12.0  # above every mask, moved toward the largest below
        assert index[-1] == 3 and 0.0 <= s[-1] <= 0.5  # the smallest, toward 0
        for i, v in zip(index[1:-1], s[1:-1]):
            nxt = scales[i + 1] if i + 1 < len(scales) else 0.0
            assert nxt <= v <= scales[i]
