"""CGC: label map from overlapping masks, 2D loss against a loop reference, 3D spatial term."""

from __future__ import annotations

import math

import pytest
import torch
from baseline_helpers import make_sample

from baselines.cgc import (
    ContrastiveGaussianClustering,
    cgc_2d_loss,
    cgc_labels,
    cgc_loss,
    cgc_spatial_loss,
    min_mask_pixels_for,
    nearest_farthest,
)
from trase.objectives import ObjectiveInputError


def test_labels_smallest_covering_mask_wins_and_small_masks_drop():
    # masks: 0 whole (area 500), 1 part inside 0 (area 150), 2 tiny (area 50), 3 same area as 1
    member = torch.tensor(
        [
            [1, 0, 0, 0],  # whole only -> 0
            [1, 1, 0, 0],  # part wins -> 1
            [1, 1, 0, 1],  # tie 150/150 -> lowest index 1
            [0, 0, 1, 0],  # only the tiny mask (<= 100) -> dropped
            [1, 0, 1, 0],  # tiny mask is smallest -> its label, dropped (not relabelled)
            [0, 0, 0, 0],  # no mask
        ],
        dtype=torch.bool,
    )
    labels = cgc_labels(member, torch.tensor([500.0, 150.0, 50.0, 150.0]), min_mask_pixels=100)
    assert labels.tolist() == [0, 1, 1, -1, -1, -1]
    # with no threshold the tiny mask keeps its pixels
    assert cgc_labels(member, torch.tensor([500.0, 150.0, 50.0, 150.0]), 0).tolist()[3:5] == [2, 2]
    # a mask of exactly min_mask_pixels is dropped ("<= 100 dropped")
    assert cgc_labels(member[:, :1], torch.tensor([100.0]), 100).tolist() == [
        -1,
        -1,
        -1,
        -1,
        -1,
        -1,
    ]


def _reference_2d(f: torch.Tensor, labels: torch.Tensor) -> float:
    """Plain loops after the public formula, averaged over labelled pixels."""
    keep = [i for i in range(len(labels)) if labels[i] >= 0]
    ids = sorted({int(labels[i]) for i in keep})
    fn = [f[i] / max(float(f[i].norm()), 1e-9) for i in range(len(labels))]
    means, phis = {}, {}
    for m in ids:
        members = [fn[i] for i in keep if labels[i] == m]
        n = len(members)
        mean = sum(members) / n
        spread = sum(float((x - mean).norm()) for x in members)
        means[m] = mean
        phis[m] = min(max(10 * spread / (n * math.log(n + 100)), 0.1), 1.0)
    total = 0.0
    for i in keep:
        logits = {m: float(fn[i] @ means[m]) / phis[m] for m in ids}
        den = sum(math.exp(v) for v in logits.values())
        total += -math.log(math.exp(logits[int(labels[i])]) / den)
    return total / len(keep)


def test_2d_loss_hand_computed_with_unclipped_temperature():
    # label 0: (1,0),(0.8,0.6): mean (0.9,0.3), distances sqrt(0.1) each ->
    # phi_0 = 10 * 2 sqrt(.1) / (2 ln 102) = 0.6837 (not clipped); label 1: (0,1) alone -> phi 0.1
    f = torch.tensor([[2.0, 0.0], [0.8, 0.6], [0.0, 3.0]], dtype=torch.float64)
    labels = torch.tensor([0, 0, 1])
    loss, stats = cgc_2d_loss(f, labels)
    phi0 = 10 * 2 * math.sqrt(0.1) / (2 * math.log(102))
    assert stats["phi_mean"] == pytest.approx((phi0 + 0.1) / 2)
    d = torch.float64
    m0, m1 = torch.tensor([0.9, 0.3], dtype=d), torch.tensor([0.0, 1.0], dtype=d)
    x = [torch.tensor(v, dtype=d) for v in ([1.0, 0.0], [0.8, 0.6], [0.0, 1.0])]
    expected = 0.0
    for xi, own in zip(x, (0, 0, 1)):
        logits = torch.stack([xi @ m0 / phi0, xi @ m1 / 0.1])
        expected += -torch.log_softmax(logits, 0)[own].item()
    assert float(loss) == pytest.approx(expected / 3, abs=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_2d_loss_matches_loop_reference(seed):
    g = torch.Generator().manual_seed(seed)
    f = torch.randn(40, 5, generator=g, dtype=torch.float64) * 0.2 + torch.randn(
        1, 5, generator=g, dtype=torch.float64
    )
    labels = torch.randint(-1, 4, (40,), generator=g)
    loss, _ = cgc_2d_loss(f, labels)
    assert float(loss) == pytest.approx(_reference_2d(f, labels), abs=1e-9)


def test_temperature_is_detached():
    # Same loss value, but the gradient must not flow through phi: compare with phi frozen.
    g = torch.Generator().manual_seed(3)
    f = (
        torch.randn(10, 3, generator=g, dtype=torch.float64) * 0.05 + torch.tensor([1.0, 0, 0])
    ).requires_grad_(True)
    labels = torch.tensor([0] * 5 + [1] * 5)
    f.data[5:] = f.data[5:] + torch.tensor([0.0, 0.2, 0.0], dtype=torch.float64)
    loss, _ = cgc_2d_loss(f, labels)
    (grad,) = torch.autograd.grad(loss, f)
    fn = torch.nn.functional.normalize(f, dim=1)
    with torch.no_grad():
        phi, raws = [], []
        for m in (0, 1):
            x = fn[labels == m]
            n = x.shape[0]
            raw = float(10 * (x - x.mean(0)).norm(dim=1).sum() / (n * math.log(n + 100)))
            raws.append(raw)
            phi.append(min(max(raw, 0.1), 1.0))
    assert any(0.1 < r < 1.0 for r in raws)  # an unclipped temperature has a local slope
    means = torch.stack([fn[labels == m].mean(0) for m in (0, 1)])
    frozen = torch.nn.functional.cross_entropy(
        fn @ means.T / torch.tensor(phi, dtype=torch.float64), labels
    )
    (grad_frozen,) = torch.autograd.grad(frozen, f)
    torch.testing.assert_close(grad, grad_frozen)


def test_objective_uses_label_map_and_threshold():
    s = make_sample([[1, 0], [1, 1], [0, 1], [0, 1]], areas=[300.0, 50.0])
    f = torch.randn(4, 3, dtype=torch.float64)
    _, stats = ContrastiveGaussianClustering()(f, s)
    assert stats["n_labels"] == 1 and stats["n_labelled"] == 1  # mask 1 (50 px) dropped
    _, stats = ContrastiveGaussianClustering(min_mask_pixels=10)(f, s)
    assert stats["n_labels"] == 2 and stats["n_labelled"] == 4
    assert float(cgc_loss(f, s, 10)[0]) == pytest.approx(
        float(ContrastiveGaussianClustering(10)(f, s)[0])
    )


def test_min_mask_pixels_scaling():
    assert min_mask_pixels_for(270, 480) == 100
    assert min_mask_pixels_for(128, 128) == 13
    assert min_mask_pixels_for(4, 4) == 1
    with pytest.raises(ObjectiveInputError, match="image size"):
        min_mask_pixels_for(0, 10)
    with pytest.raises(ObjectiveInputError, match="min_mask_pixels"):
        ContrastiveGaussianClustering(min_mask_pixels=-1)


def _reference_spatial(f, xyz, pick, k_pull=2, k_push=5):
    d = torch.cdist(xyz[pick], xyz)
    near = d.argsort(dim=1)[:, :k_pull]
    far = d.argsort(dim=1, descending=True)[:, :k_push]
    cos = torch.nn.functional.cosine_similarity
    pull = torch.stack([cos(f[p][None], f[near[i]], dim=-1) for i, p in enumerate(pick)]).mean()
    push = torch.stack([cos(f[p][None], f[far[i]], dim=-1) for i, p in enumerate(pick)]).mean()
    return 0.05 * torch.sigmoid(1 - pull) + 0.15 * torch.sigmoid(push)


def test_spatial_loss_matches_reference_and_gradchecks():
    g = torch.Generator().manual_seed(0)
    xyz = torch.rand(30, 3, generator=g, dtype=torch.float64)
    f = torch.randn(30, 4, generator=g, dtype=torch.float64, requires_grad=True)
    pick = torch.randperm(30, generator=torch.Generator().manual_seed(7))[:10]
    got = cgc_spatial_loss(f, xyz, torch.Generator().manual_seed(7), sample_size=10)
    torch.testing.assert_close(got, _reference_spatial(f, xyz, pick))
    assert torch.autograd.gradcheck(
        lambda x: cgc_spatial_loss(x, xyz, torch.Generator().manual_seed(7), sample_size=10), (f,)
    )


def test_spatial_loss_degenerate_and_bad_input():
    obj = ContrastiveGaussianClustering()
    for n in (0, 1, 3):
        f = torch.zeros(n, 4, dtype=torch.float64, requires_grad=True)
        loss = obj.gaussian_loss(f, torch.zeros(n, 3, dtype=torch.float64))
        assert torch.isfinite(loss)
        loss.backward()
        assert torch.isfinite(f.grad).all()
    with pytest.raises(ObjectiveInputError, match="xyz"):
        obj.gaussian_loss(torch.zeros(4, 2), torch.zeros(5, 3))
    assert (
        ContrastiveGaussianClustering(weight_3d=0.0).gaussian_loss(
            torch.zeros(4, 2), torch.zeros(4, 3)
        )
        is None
    )


def test_spatial_loss_caps_points():
    xyz = torch.rand(50, 3, dtype=torch.float64)
    f = torch.randn(50, 4, dtype=torch.float64)
    loss = cgc_spatial_loss(f, xyz, torch.Generator().manual_seed(0), sample_size=5, max_points=20)
    assert torch.isfinite(loss)


def test_neighbour_table_equals_direct_search_and_is_reused():
    g = torch.Generator().manual_seed(4)
    xyz = torch.rand(60, 3, generator=g, dtype=torch.float64)
    f = torch.randn(60, 4, generator=g, dtype=torch.float64)
    obj = ContrastiveGaussianClustering(sample_size=20)
    for seed in range(3):
        cached = obj.gaussian_loss(f, xyz, torch.Generator().manual_seed(seed))
        direct = cgc_spatial_loss(f, xyz, torch.Generator().manual_seed(seed), sample_size=20)
        torch.testing.assert_close(cached, direct)
    table = obj._table
    assert table is not None and 20 <= int(table.known.sum()) <= 60
    obj.gaussian_loss(f, xyz, torch.Generator().manual_seed(9))
    assert obj._table is table  # same geometry: table kept
    obj.gaussian_loss(f, xyz + 1.0, torch.Generator().manual_seed(9))
    assert obj._table is not table  # new geometry: table rebuilt
    near, far = nearest_farthest(xyz[:5], xyz, 2, 5)
    assert near[:, 0].tolist() == list(range(5))  # the nearest is the point itself
    d = torch.cdist(xyz[:5], xyz)
    assert torch.equal(far.sort(dim=1).values, d.topk(5, dim=1).indices.sort(dim=1).values)
