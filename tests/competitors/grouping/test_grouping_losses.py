"""The identity loss and the 3D regulariser of trase-bench-grouping against plain references
written here (loops, no vectorisation), and the weights' round trip through a string."""

import math

import numpy as np
import pytest
import torch

pytest.importorskip("trase_bench_grouping")

from trase_bench_grouping.identity import IdentityField, IdentityTable, pack, unpack
from trase_bench_grouping.losses import identity_loss, knn_consistency


def test_identity_loss_is_mean_cross_entropy_over_log_classes():
    g = torch.Generator().manual_seed(0)
    logits = torch.randn(7, 5, generator=g)
    target = torch.tensor([0, 1, 4, 2, 2, 3, 0])
    ref = 0.0
    for p in range(7):
        z = logits[p].tolist()
        m = max(z)
        lse = m + math.log(sum(math.exp(v - m) for v in z))
        ref += lse - z[int(target[p])]
    ref /= 7 * math.log(5)
    assert float(identity_loss(logits, target)) == pytest.approx(ref, rel=1e-6)
    # a uniform guess scores 1, whatever the number of classes
    assert float(identity_loss(torch.zeros(3, 256), torch.tensor([0, 9, 200]))) == pytest.approx(1.0)


def _reference_kl(positions, probs, anchors, k, weight):
    n, c = probs.shape
    total, count = 0.0, 0
    for a in anchors:
        d = [float(np.linalg.norm(positions[a] - positions[j])) for j in range(n)]
        for j in np.argsort(d, kind="stable")[:k]:
            total += sum(probs[a, x] * (math.log(probs[a, x] + 1e-10) - math.log(probs[j, x] + 1e-10))
                         for x in range(c))
            count += 1
    return weight * total / count / c


def test_knn_consistency_matches_a_plain_reference():
    rng = np.random.default_rng(3)
    pos = rng.normal(size=(40, 3))
    probs = torch.softmax(torch.from_numpy(rng.normal(size=(40, 6))), dim=1)
    g = torch.Generator().manual_seed(5)
    got = float(knn_consistency(torch.from_numpy(pos), probs, k=4, weight=2.0, sample_size=10, generator=g))
    anchors = torch.randperm(40, generator=torch.Generator().manual_seed(5))[:10].numpy()
    assert got == pytest.approx(_reference_kl(pos, probs.numpy(), anchors, 4, 2.0), rel=1e-5)


def test_knn_consistency_is_zero_where_neighbours_agree_and_pulls_them_together():
    pos = torch.cat([torch.zeros(10, 3), torch.full((10, 3), 5.0)]) + 0.01 * torch.randn(20, 3)
    same = torch.softmax(torch.tensor([[2.0, 0.0]]).repeat(20, 1), dim=1)
    assert float(knn_consistency(pos, same, k=5, sample_size=20)) == pytest.approx(0.0, abs=1e-7)
    logits = torch.randn(20, 2, requires_grad=True)
    loss = knn_consistency(pos, torch.softmax(logits, dim=1), k=5, sample_size=20)
    loss.backward()
    assert float(loss.detach()) > 0 and torch.isfinite(logits.grad).all()


def test_knn_consistency_gradient_reproduces_its_bits_on_two_threads():
    """Neighbours repeat across anchors, so the gradient sums into the same rows; on several
    threads that sum must not depend on which thread adds first (advanced indexing's backward
    does: 4 distinct gradients in 10 on two threads)."""
    g = torch.Generator().manual_seed(0)
    pos, logits = torch.rand(3000, 3, generator=g), torch.randn(3000, 256, generator=g)
    before = torch.get_num_threads()
    grads = set()
    try:
        for threads in [2] * 10 + [1]:  # and one thread gives the same bits as two
            torch.set_num_threads(threads)
            leaf = logits.clone().requires_grad_(True)
            knn_consistency(pos, torch.softmax(leaf, dim=1), 5, 2.0, 200000, 1000,
                            torch.Generator().manual_seed(1)).backward()
            grads.add(leaf.grad.numpy().tobytes())
    finally:
        torch.set_num_threads(before)
    assert len(grads) == 1


def test_max_points_keeps_a_subset():
    pos, probs = torch.randn(50, 3), torch.softmax(torch.randn(50, 3), dim=1)
    out = knn_consistency(pos, probs, k=3, max_points=20, sample_size=100)
    assert torch.isfinite(out) and float(out) >= 0


def test_weights_round_trip_through_a_string():
    field = IdentityField(8, width=16, depth=3, pos_freqs=2, time_freqs=1, generator=torch.Generator().manual_seed(1))
    again = unpack(IdentityField(8, width=16, depth=3, pos_freqs=2, time_freqs=1), pack(field))
    x = torch.randn(5, 3)
    assert torch.equal(field(x, 0.3), again(x, 0.3))
    assert not torch.equal(field(x, 0.0), field(x, 1.0))  # the field depends on time
    table = IdentityTable(5, 4, generator=torch.Generator().manual_seed(0))
    assert torch.equal(table(x, 0.0), table(x, 1.0))
    with pytest.raises(ValueError):
        unpack(torch.nn.Linear(3, 2), pack(torch.nn.Linear(4, 2)))
