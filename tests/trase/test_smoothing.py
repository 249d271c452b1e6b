import numpy as np
import torch

from trase.smoothing import knn_indices, smooth_features


def test_knn_includes_self_and_handles_small_n():
    xyz = np.array([[0, 0, 0], [1, 0, 0], [3, 0, 0]], float)
    idx = knn_indices(xyz, K=2)
    assert idx.tolist() == [[0, 1], [1, 0], [2, 1]]
    assert knn_indices(xyz, K=16).shape == (3, 3)  # N < K
    assert knn_indices(xyz, K=0).shape == (3, 0)
    assert knn_indices(np.zeros((0, 3)), K=4).shape == (0, 0)
    dup = knn_indices(np.zeros((3, 3)), K=3)  # all points equal
    assert dup[:, 0].tolist() == [0, 1, 2]


def test_smooth_is_mean_of_normalised_neighbours():
    f = torch.tensor([[2.0, 0.0], [0.0, 3.0], [0.0, 0.0]])
    knn = torch.tensor([[0, 1], [1, 0], [2, 0]])
    out = smooth_features(f, knn, n_keep=None)
    torch.testing.assert_close(out, torch.tensor([[0.5, 0.5], [0.5, 0.5], [0.5, 0.0]]))
    assert torch.equal(smooth_features(f, torch.zeros(3, 0, dtype=torch.long)), f)


def test_dropout_uses_shared_slots_and_is_seeded():
    torch.manual_seed(0)
    f = torch.randn(50, 4, requires_grad=True)
    knn = knn_indices(torch.randn(50, 3), K=16)
    g1, g2 = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    a = smooth_features(f, knn, 8, g1)
    b = smooth_features(f, knn, 8, g2)
    assert torch.equal(a, b)
    a.sum().backward()
    # the gaussian itself is slot 0; gradient flows and is finite
    assert torch.isfinite(f.grad).all()
    # zero features give finite, zero output
    z = smooth_features(torch.zeros(5, 3), knn_indices(torch.randn(5, 3), 4), 2)
    assert torch.isfinite(z).all() and z.abs().max() == 0
