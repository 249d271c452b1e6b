"""The deformation network's matrix products on the CPU, through torch (MKL) or OpenBLAS.

The network's products are most of a reconstruction step on the CPU. torch computes them with
MKL, whose fast branches are the processor's own: MKL keeps its bits the same on every x86-64
vendor only in its COMPATIBLE branch (SSE2), which runs the network's ``[N, 64] @ [64, 64]``
products about 2x slower than OpenBLAS with its Haswell (AVX2) kernels, a choice OpenBLAS
honours on every vendor (``OPENBLAS_CORETYPE``). A process that pins its numerics names the
engine in ``$TRASE_PRODUCTS`` (read once, at import):

* ``torch`` (the default): ``torch.nn.functional.linear``.
* ``openblas``: ``linear`` below, forward and backward as OpenBLAS products (float32 and float64
  tensors on the CPU; any other tensor goes to torch). ``relu_sum`` and ``relu_layer`` compute a
  hidden layer's additions and ReLU in the same chunk loop as its products, with the same
  operations in the same order as the separate steps, so the same bits. The rows are cut into chunks of a fixed
  size, each multiplied by one single-threaded OpenBLAS call on one of numba's threads (the
  OpenMP pool torch shares, so nothing spins against it); a weight's gradient sums the chunks'
  in chunk order. The bits therefore do not depend on the thread count (MKL's do).

``trase.blas_kernels`` holds the numba loops and the plain products they are tested against.
"""

from __future__ import annotations

import os

import numpy as np
import torch
import torch.nn.functional as F

ENV = "TRASE_PRODUCTS"
ENGINES = ("torch", "openblas")


def engine_from_env() -> str:
    """The engine ``$TRASE_PRODUCTS`` names (``torch`` when unset); a clear error otherwise."""
    value = os.environ.get(ENV, "").strip() or "torch"
    if value not in ENGINES:
        raise ValueError(f"${ENV}={value!r}: expected one of {', '.join(ENGINES)}")
    return value


_engine = engine_from_env()


def engine() -> str:
    """The engine this process computes the network's products with."""
    return _engine


def set_engine(name: str) -> str:
    """Switch the engine (tests, benchmarks); returns the previous one."""
    global _engine
    if name not in ENGINES:
        raise ValueError(f"products engine must be one of {', '.join(ENGINES)}, got {name!r}")
    previous, _engine = _engine, name
    return previous


def _array(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().numpy())


def _products():
    """The numba kernels, imported (and OpenBLAS set to one thread a call) on first use: a
    process on torch's engine never loads them."""
    from trase import blas_kernels

    blas_kernels.single_threaded_blas()
    return blas_kernels


def _chunked(parallel_kernel, chunk_kernel, rows: int, *arrays) -> None:
    """A chunk kernel over all chunks of ``rows``: over numba's threads, or in order on this
    thread when the count is one (the bits are the same either way)."""
    from trase.threads import numba_threads

    with numba_threads() as n:
        if n > 1:
            parallel_kernel(*arrays)
        else:
            _products().on_this_thread(chunk_kernel, rows, *arrays)


def _rows_times(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a [N, K] @ b [K, M] -> [N, M], chunked over the rows."""
    kernels = _products()
    out = np.empty((a.shape[0], b.shape[1]), dtype=a.dtype)
    _chunked(kernels.rows_times, kernels.rows_chunk, a.shape[0], a, b, out)
    return out


def _transposed_times(g: np.ndarray, x: np.ndarray) -> np.ndarray:
    """g [N, O]^T @ x [N, I] -> [O, I], summed over the row chunks in their order."""
    kernels = _products()
    partial = np.empty((kernels.n_chunks(g.shape[0]), g.shape[1], x.shape[1]), dtype=g.dtype)
    _chunked(kernels.transposed_times, kernels.transposed_chunk, g.shape[0], g, x, partial)
    return kernels.sum_in_order(partial)


class _BlasLinear(torch.autograd.Function):
    """y = x W^T + b with OpenBLAS's products; the gradients likewise."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
        # x [N, I], weight [O, I], bias [O] or None -> [N, O]
        out = _rows_times(_array(x), np.ascontiguousarray(_array(weight).T))
        if bias is not None:
            out += _array(bias)
        ctx.save_for_backward(x, weight)
        ctx.has_bias = bias is not None
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        x, weight = ctx.saved_tensors
        g = _array(grad)  # [N, O]
        grad_x = torch.from_numpy(_rows_times(g, _array(weight))) if ctx.needs_input_grad[0] else None  # [N, I]
        grad_w = torch.from_numpy(_transposed_times(g, _array(x))) if ctx.needs_input_grad[1] else None  # [O, I]
        grad_b = grad.sum(0) if ctx.has_bias and ctx.needs_input_grad[2] else None  # [O]
        return grad_x, grad_w, grad_b


def _relu_sum(x: np.ndarray, wt: np.ndarray, x2: np.ndarray | None, wt2: np.ndarray | None,
              row: np.ndarray) -> np.ndarray:
    """relu(x wt [+ x2 wt2] + row) -> [N, M], chunked over the rows (wt [K, M] transposed weights)."""
    kernels = _products()
    two = x2 is not None
    if not two:
        x2, wt2 = x[:, :0], wt[:0]
    out = np.empty((x.shape[0], wt.shape[1]), dtype=x.dtype)
    _chunked(kernels.relu_sum_times, kernels.relu_sum_chunk, x.shape[0], x, wt, x2, wt2, two, row, out)
    return out


def _relu_grad(grad: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The gradient [N, M] through the ReLU whose output is y [N, M]."""
    kernels = _products()
    out = np.empty_like(grad)
    _chunked(kernels.relu_grad_times, kernels.relu_grad_chunk, grad.shape[0], grad, y, out)
    return out


def _row_gradient(g: torch.Tensor, row_shape: torch.Size) -> torch.Tensor:
    """The gradient of a row [O] or [1, O] added to every row of g [N, O], as autograd gives
    it: summed over the rows, except a [1, O] row on one row, whose gradient passes unchanged
    (a sum would turn -0 into +0)."""
    if tuple(g.shape) == tuple(row_shape):
        return g
    return g.sum(0).reshape(row_shape)


class _BlasReluSum(torch.autograd.Function):
    """y = relu(x W^T [+ x2 W2^T] + row): a hidden layer of the network, its sums and ReLU done
    in the products' chunk loop while the chunk is in cache. The same operations in the same
    order as ``linear``, the additions and ``F.relu``, so the same bits."""

    @staticmethod
    def forward(ctx, row, x, weight, x2, weight2):
        # row [O] or [1, O]; x [N, I], weight [O, I]; x2 [N, I2], weight2 [O, I2] or None -> [N, O]
        wt = np.ascontiguousarray(_array(weight).T)
        wt2 = None if x2 is None else np.ascontiguousarray(_array(weight2).T)
        a2 = None if x2 is None else _array(x2)
        y = torch.from_numpy(_relu_sum(_array(x), wt, a2, wt2, _array(row).reshape(-1)))
        ctx.save_for_backward(x, weight, x2, weight2, y)
        ctx.row_shape = row.shape
        return y

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        x, weight, x2, weight2, y = ctx.saved_tensors
        g = _relu_grad(_array(grad), _array(y))  # [N, O]: the gradient before the ReLU
        needs = ctx.needs_input_grad
        grad_row = _row_gradient(torch.from_numpy(g), ctx.row_shape) if needs[0] else None  # [O] or [1, O]
        grads = [grad_row]
        for k, (inp, w) in enumerate(((x, weight), (x2, weight2))):
            grads.append(torch.from_numpy(_rows_times(g, _array(w))) if needs[1 + 2 * k] else None)  # [N, I]
            grads.append(torch.from_numpy(_transposed_times(g, _array(inp))) if needs[2 + 2 * k] else None)  # [O, I]
        return tuple(grads)


def _blas_ok(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> bool:
    tensors = (x, weight) if bias is None else (x, weight, bias)
    return (x.dim() == 2 and weight.dim() == 2 and x.dtype in (torch.float32, torch.float64)
            and all(t.device.type == "cpu" and t.dtype == x.dtype and t.layout == torch.strided for t in tensors))


def linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None = None) -> torch.Tensor:
    """``F.linear(x, weight, bias)`` computed by this process's engine. x [N, I]; weight [O, I]."""
    if _engine == "openblas" and _blas_ok(x, weight, bias):
        return _BlasLinear.apply(x, weight, bias)
    return F.linear(x, weight, bias)


def layer(module: torch.nn.Linear, x: torch.Tensor) -> torch.Tensor:
    """``module(x)`` for an ``nn.Linear``, by this process's engine."""
    return linear(x, module.weight, module.bias)


def relu_sum(row: torch.Tensor, x: torch.Tensor, weight: torch.Tensor, x2: torch.Tensor | None = None,
             weight2: torch.Tensor | None = None) -> torch.Tensor:
    """``F.relu((linear(x, weight) [+ linear(x2, weight2)]) + row)`` by this process's engine: the
    network's split layers (row [1, O] from the time encoding and the bias)."""
    if tuple(row.shape) not in ((weight.shape[0],), (1, weight.shape[0])):
        raise ValueError(f"relu_sum: row {tuple(row.shape)} is not [O] or [1, O] for a weight {tuple(weight.shape)}")
    if _engine == "openblas" and _blas_ok(x, weight, row) and (x2 is None or _blas_ok(x2, weight2, row)):
        return _BlasReluSum.apply(row, x, weight, x2, weight2)
    out = F.linear(x, weight)
    if x2 is not None:
        out = out + F.linear(x2, weight2)
    return F.relu(out + row)


def relu_layer(module: torch.nn.Linear, x: torch.Tensor) -> torch.Tensor:
    """``F.relu(module(x))`` for an ``nn.Linear`` by this process's engine (torch's: one
    ``F.linear`` with its bias, then the ReLU)."""
    if _engine == "openblas" and module.bias is not None and _blas_ok(x, module.weight, module.bias):
        return _BlasReluSum.apply(module.bias, x, module.weight, None, None)
    return F.relu(layer(module, x))
