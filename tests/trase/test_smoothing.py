import numpy as np
import pytest
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
    # K = 0: no neighbours, each feature only normalised (= K = 1); zero stays zero
    none = smooth_features(f, torch.zeros(3, 0, dtype=torch.long))
    torch.testing.assert_close(none, torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]))
    torch.testing.assert_close(none, smooth_features(f, torch.arange(3)[:, None], n_keep=None))


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


def _fused_vs_reference(f0, slots, gy):
    out = {}
    for impl in ("reference", "fused"):
        f = f0.clone().requires_grad_(True)
        y = smooth_features(f, slots, None, impl=impl)
        y.backward(gy)
        out[impl] = (y.detach(), f.grad)
    return out


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-6), (torch.float64, 1e-12)])
def test_fused_matches_reference_values_and_gradients(dtype, tol):
    g = torch.Generator().manual_seed(1)
    N, D = 300, 12
    f0 = torch.randn(N, D, generator=g, dtype=dtype) * torch.rand(N, 1, generator=g, dtype=dtype) * 3
    f0[5] = 0.0  # zero-norm row: clamp active (gradient g / eps in both)
    f0[7] = 1e-13  # below eps too
    slots = knn_indices(torch.randn(N, 3, generator=g), K=9)[:, [0, 3, 3, 8]]  # repeated slot
    gy = torch.randn(N, D, generator=g, dtype=dtype)
    r = _fused_vs_reference(f0, slots, gy)
    (yr, gr), (yf, gf) = r["reference"], r["fused"]
    assert yf.dtype == dtype and gf.dtype == dtype
    torch.testing.assert_close(yf, yr, rtol=0, atol=tol)
    ok = torch.ones(N, dtype=torch.bool)
    ok[[5, 7]] = False  # gradients of ~1e12 there: compare relatively
    torch.testing.assert_close(gf[ok], gr[ok], rtol=0, atol=tol * float(gr[ok].abs().max()))
    torch.testing.assert_close(gf[~ok], gr[~ok], rtol=1e-5, atol=0)
    assert torch.isfinite(gf).all()


def test_fused_threads_give_identical_results():
    g = torch.Generator().manual_seed(2)
    N, D = 5000, 32  # above the parallel threshold
    f0 = torch.randn(N, D, generator=g)
    slots = knn_indices(torch.randn(N, 3, generator=g), K=16)[:, :8]
    gy = torch.randn(N, D, generator=g)
    old = torch.get_num_threads()
    res = []
    try:
        for nt in (1, 2):
            torch.set_num_threads(nt)
            res.append(_fused_vs_reference(f0, slots, gy)["fused"])
    finally:
        torch.set_num_threads(old)
    assert torch.equal(res[0][0], res[1][0]) and torch.equal(res[0][1], res[1][1])


def test_impl_selection_errors():
    f = torch.randn(4, 3)
    knn = knn_indices(torch.randn(4, 3), 2)
    with pytest.raises(ValueError, match="unknown impl"):
        smooth_features(f, knn, None, impl="fast")
    with pytest.raises(ValueError, match="float32/float64"):
        smooth_features(f.half(), knn, None, impl="fused")
    # auto on half precision runs the reference
    assert smooth_features(f.to(torch.bfloat16), knn, None).dtype == torch.bfloat16
