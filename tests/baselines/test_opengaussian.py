"""OpenGaussian: silhouette means, cohesion, rank-weighted separation, by hand and by loops."""

from __future__ import annotations

import pytest
import torch
from baseline_helpers import make_sample

from baselines.opengaussian import (
    OpenGaussianObjective,
    opengaussian_loss,
    rank_weights,
    separation,
)
from trase.objectives import ObjectiveInputError, PixelSample

D = torch.float64


def test_two_masks_hand_computed_with_silhouette():
    # mask 0: pixels (0,0) alpha .9 and (2,0) alpha .5 (outside the silhouette) -> mean (0,0);
    # its cohesion uses both pixels: (0 + 2) / 2 = 1. mask 1: two pixels at (1,0) -> cohesion 0.
    # inter: N = 2, weights 1, g = 1 / (1 + 1) = 0.5 -> 0.5. L = 0.5 + 0.1 * 0.5 = 0.55.
    s = make_sample([[1, 0], [1, 0], [0, 1], [0, 1]], alpha=[0.9, 0.5, 0.8, 0.8])
    f = torch.tensor([[0.0, 0.0], [2.0, 0.0], [1.0, 0.0], [1.0, 0.0]], dtype=D)
    loss, stats = opengaussian_loss(f, s)
    assert stats["loss_inter"] == pytest.approx(0.5)
    assert stats["loss_intra"] == pytest.approx(0.5)
    assert float(loss) == pytest.approx(0.55)
    assert stats["n_masks"] == 2


def test_rank_weighted_separation_three_masks_by_hand():
    # means at x = 0, 1, 3: g01 = 1/2, g02 = 1/10, g12 = 1/5.
    # row 0 [0, .5, .1] -> ranks [0, 2, 1] -> w [.1, 1, .55]; row 1 [.5, 0, .2] -> w [1, .1, .55];
    # row 2 [.1, .2, 0] -> w [.55, 1, .1]. sum w g = .555 + .61 + .255 = 1.42; / (3 * 2).
    means = torch.tensor([[0.0], [1.0], [3.0]], dtype=D)
    assert float(separation(means)) == pytest.approx(1.42 / 6)
    g = torch.tensor([[0, 0.5, 0.1], [0.5, 0, 0.2], [0.1, 0.2, 0]], dtype=D)
    expected = torch.tensor([[0.1, 1, 0.55], [1, 0.1, 0.55], [0.55, 1, 0.1]], dtype=D)
    torch.testing.assert_close(rank_weights(g), expected)


def _reference(f, member, alpha, thr=0.7):
    """Loops after the public formulas."""
    means, masks = [], []
    for m in range(member.shape[1]):
        inside = [i for i in range(f.shape[0]) if member[i, m] and alpha[i] > thr]
        if inside:
            means.append(sum(f[i] for i in inside) / len(inside))
            masks.append(m)
    intra = 0.0
    for mean, m in zip(means, masks):
        pix = [i for i in range(f.shape[0]) if member[i, m]]
        intra += sum(float((f[i] - mean).norm()) for i in pix) / len(pix)
    intra = intra / len(masks) if masks else 0.0
    n = len(means)
    inter = 0.0
    if n >= 2:
        for a in range(n):
            row = [
                0.0 if a == b else 1.0 / (float(((means[a] - means[b]) ** 2).sum()) + 1)
                for b in range(n)
            ]
            order = sorted(range(n), key=lambda b: row[b])
            for rank, b in enumerate(order):
                inter += (0.1 + 0.9 * rank / (n - 1)) * row[b]
        inter /= n * (n - 1)
    return inter + 0.1 * intra


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_loop_reference(seed):
    g = torch.Generator().manual_seed(seed)
    f = torch.randn(20, 3, generator=g, dtype=D)
    member = torch.rand(20, 5, generator=g) < 0.4
    alpha = torch.rand(20, generator=g, dtype=D)
    s = make_sample(member, alpha=alpha)
    loss, _ = opengaussian_loss(f, s)
    assert float(loss) == pytest.approx(_reference(f, member, alpha), abs=1e-9)


def test_mask_outside_silhouette_is_dropped():
    s = make_sample([[1, 0], [1, 0], [0, 1]], alpha=[0.9, 0.9, 0.1])
    _, stats = OpenGaussianObjective()(torch.randn(3, 2, dtype=D), s)
    assert stats["n_masks"] == 1 and stats["loss_inter"] == 0.0


def test_missing_alpha_and_bad_threshold_fail_clearly():
    m = torch.ones(2, 1, dtype=torch.bool)
    s = PixelSample(torch.arange(2), m, torch.ones(1), torch.ones(2))
    with pytest.raises(ObjectiveInputError, match="rendered alpha"):
        OpenGaussianObjective()(torch.zeros(2, 3), s)
    with pytest.raises(ObjectiveInputError, match="alpha_threshold"):
        OpenGaussianObjective(alpha_threshold=1.5)
