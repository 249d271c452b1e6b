"""The deformation network's products through OpenBLAS: the same products as torch's up to
rounding, gradients included, and the same bits on any thread count."""

import numba
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from trase import blas_kernels, blas_linear
from trase.deformation import DeformMLP
from trase.threads import torch_threads


@pytest.fixture
def openblas():
    previous = blas_linear.set_engine("openblas")
    yield
    blas_linear.set_engine(previous)


def _inputs(n, i, o, dtype=torch.float32, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return (torch.randn(n, i, generator=gen, dtype=dtype), torch.randn(o, i, generator=gen, dtype=dtype),
            torch.randn(o, generator=gen, dtype=dtype))


@pytest.mark.parametrize("n", [0, 1, 1023, 1024, 2500])
def test_kernels_match_the_plain_products(n):
    rng = np.random.default_rng(n)
    a, b = rng.standard_normal((n, 39)).astype(np.float32), rng.standard_normal((39, 64)).astype(np.float32)
    out = np.empty((n, 64), np.float32)
    blas_kernels.rows_times(a, b, out)
    np.testing.assert_allclose(out, blas_kernels.reference_rows_times(a, b), rtol=1e-5, atol=1e-4)
    g = rng.standard_normal((n, 64)).astype(np.float32)
    partial = np.empty((blas_kernels.n_chunks(n), 64, 39), np.float32)
    blas_kernels.transposed_times(g, a, partial)
    np.testing.assert_allclose(blas_kernels.sum_in_order(partial), blas_kernels.reference_transposed_times(g, a),
                               rtol=1e-5, atol=1e-3)


def test_linear_equals_torch_forward_and_backward(openblas):
    x, w, b = _inputs(3000, 39, 64)
    grads = []
    for use in ("openblas", "torch"):
        blas_linear.set_engine(use)
        xs, ws, bs = (t.clone().requires_grad_(True) for t in (x, w, b))
        y = blas_linear.linear(xs, ws, bs)
        (y * torch.linspace(-1, 1, 64)).sum().backward()
        grads.append((y.detach(), xs.grad, ws.grad, bs.grad))
    for ours, theirs in zip(*grads):
        torch.testing.assert_close(ours, theirs, rtol=1e-5, atol=2e-4)


def test_gradients_pass_gradcheck_in_float64(openblas):
    x, w, b = (t.requires_grad_(True) for t in _inputs(7, 5, 3, dtype=torch.float64))
    assert torch.autograd.gradcheck(blas_linear.linear, (x, w, b))
    assert torch.autograd.gradcheck(lambda x, w: blas_linear.linear(x, w), (x, w))


def test_non_contiguous_inputs_and_weight_slices(openblas):
    x, w, b = _inputs(1500, 84, 64)
    xs, ws = x[:, ::2], w[:, 10:52]  # column slices, as the network's split first layer reads them
    torch.testing.assert_close(blas_linear.linear(xs, ws, b), F.linear(xs, ws, b), rtol=1e-5, atol=2e-4)


def test_bits_do_not_depend_on_the_thread_count(openblas):
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs 2 numba threads")
    x, w, b = _inputs(5000, 64, 64)
    out = {}
    for n in (1, 2):
        with torch_threads(n):
            xs, ws = x.clone().requires_grad_(True), w.clone().requires_grad_(True)
            y = blas_linear.linear(xs, ws, b)
            z = blas_linear.relu_sum(b[None], xs, ws, y, ws)  # the fused hidden layer too
            (y.square().sum() + z.sum()).backward()
            out[n] = (y.detach(), z.detach(), xs.grad, ws.grad)
    for one, two in zip(out[1], out[2]):
        assert torch.equal(one, two)


def test_other_tensors_go_to_torch(openblas):
    x, w, b = _inputs(10, 4, 3)
    assert blas_linear.linear(x.half(), w.half(), b.half()).dtype == torch.float16
    y = blas_linear.linear(x[None], w, b)  # [1, N, I]: not a 2-D product
    torch.testing.assert_close(y, F.linear(x[None], w, b))


def test_the_network_gives_torch_s_offsets_with_either_engine(openblas):
    net = DeformMLP.preset("small")
    for p in net.parameters():
        torch.nn.init.normal_(p, std=0.2)
    xyz = torch.rand(2048, 3) * 2 - 1
    ours = net(xyz, 0.3)
    blas_linear.set_engine("torch")
    theirs = net(xyz, 0.3)
    for a, b in zip(ours, theirs):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_engine_from_env_names_a_wrong_value(monkeypatch):
    monkeypatch.setenv(blas_linear.ENV, "mkl")
    with pytest.raises(ValueError, match="TRASE_PRODUCTS='mkl'"):
        blas_linear.engine_from_env()
    monkeypatch.delenv(blas_linear.ENV)
    assert blas_linear.engine_from_env() == "torch"
    with pytest.raises(ValueError, match="one of torch, openblas"):
        blas_linear.set_engine("cublas")


def _unfused(row, x, w, x2=None, w2=None):
    """The hidden layer as separate steps: products, additions, then torch's ReLU."""
    out = blas_linear.linear(x, w)
    if x2 is not None:
        out = out + blas_linear.linear(x2, w2)
    return F.relu(out + row)


@pytest.mark.parametrize("n", [0, 1, 1023, 1024, 2500])
def test_fused_relu_kernel_matches_the_plain_layer(n):
    rng = np.random.default_rng(n)
    a, b = rng.standard_normal((n, 39)).astype(np.float32), rng.standard_normal((39, 64)).astype(np.float32)
    a2, b2 = rng.standard_normal((n, 64)).astype(np.float32), rng.standard_normal((64, 64)).astype(np.float32)
    row = rng.standard_normal(64).astype(np.float32)
    out = np.empty((n, 64), np.float32)
    blas_kernels.relu_sum_times(a, b, a2, b2, True, row, out)
    np.testing.assert_allclose(out, blas_kernels.reference_relu_sum(a, b, row, a2, b2), rtol=1e-5, atol=1e-3)
    blas_kernels.relu_sum_times(a, b, a2[:, :0], b2[:0], False, row, out)
    np.testing.assert_allclose(out, blas_kernels.reference_relu_sum(a, b, row), rtol=1e-5, atol=1e-3)


@pytest.mark.parametrize("two", [False, True])
def test_fused_relu_layers_give_the_unfused_bits(openblas, two):
    """Forward and every gradient bit for bit as the products, the additions and F.relu one
    after another: fusing them changes no run."""
    x, w, _ = _inputs(2500, 39, 64, seed=1)
    x2, w2, b = _inputs(2500, 64, 64, seed=2)
    row = b[None]  # [1, O], as the time encoding's row
    results = []
    for fn in (blas_linear.relu_sum, _unfused):
        leaves = [t.clone().requires_grad_(True) for t in ((row, x, w, x2, w2) if two else (row, x, w))]
        y = fn(*leaves)
        (y * torch.linspace(-1, 1, 64)).sum().backward()
        results.append([y.detach()] + [t.grad for t in leaves])
    for fused, plain in zip(*results):
        assert torch.equal(fused, plain)


def test_fused_relu_keeps_torch_s_nan_and_signed_zero(openblas):
    layer = torch.nn.Linear(2, 3)
    with torch.no_grad():
        layer.weight.zero_()
        layer.bias.copy_(torch.tensor([float("nan"), -0.0, -1.0]))
    x = torch.ones(1100, 2)
    ours, theirs = blas_linear.relu_layer(layer, x), F.relu(F.linear(x, layer.weight, layer.bias))
    assert torch.equal(torch.isnan(ours), torch.isnan(theirs))
    assert torch.equal(torch.signbit(ours[:, 1:]), torch.signbit(theirs[:, 1:]))
    assert torch.equal(ours[:, 1:], theirs[:, 1:])


def test_fused_relu_gradcheck_in_float64(openblas):
    x, w, row = (t.requires_grad_(True) for t in _inputs(9, 5, 4, dtype=torch.float64, seed=3))
    x2, w2, _ = (t.requires_grad_(True) for t in _inputs(9, 6, 4, dtype=torch.float64, seed=4))
    assert torch.autograd.gradcheck(blas_linear.relu_sum, (row, x, w, x2, w2))


def test_fused_relu_row_gradient_on_one_row_passes_unchanged(openblas):
    """One row: autograd hands a [1, O] row the gradient as it is (a sum would turn -0 into +0)."""
    x, w = torch.ones(1, 2), torch.zeros(2, 2)
    grads = []
    for fn in (blas_linear.relu_sum, _unfused):
        row = torch.zeros(1, 2, requires_grad=True)
        fn(row, x, w).backward(torch.tensor([[-0.0, -0.0]]))
        grads.append(row.grad)
    assert torch.equal(torch.signbit(grads[0]), torch.signbit(grads[1]))


def test_fused_relu_refuses_a_row_of_the_wrong_size(openblas):
    x, w, _ = _inputs(10, 4, 3)
    with pytest.raises(ValueError, match=r"row \(1,\) is not \[O\] or \[1, O\]"):
        blas_linear.relu_sum(torch.zeros(1), x, w)


def test_fused_relu_refuses_a_column_row(openblas):
    x, w, b = _inputs(3, 4, 3)
    with pytest.raises(ValueError, match=r"row \(3, 1\) is not \[O\] or \[1, O\]"):
        blas_linear.relu_sum(b[:, None], x, w)
