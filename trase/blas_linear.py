"""The deformation network's matrix products on the CPU, through torch (MKL) or OpenBLAS.

The network's products are most of a reconstruction step on the CPU. torch computes them with
MKL, whose fast branches are the processor's own: MKL keeps its bits the same on every x86-64
vendor only in its COMPATIBLE branch (SSE2), which runs the network's ``[N, 64] @ [64, 64]``
products about 2x slower than OpenBLAS with its Haswell (AVX2) kernels, a choice OpenBLAS
honours on every vendor (``OPENBLAS_CORETYPE``). A process that pins its numerics names the
engine in ``$TRASE_PRODUCTS`` (read once, at import):

* ``torch`` (the default): ``torch.nn.functional.linear``.
* ``openblas``: ``linear`` below, forward and backward as OpenBLAS products (float32 and float64
  tensors on the CPU; any other tensor goes to torch). The rows are cut into chunks of a fixed
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


def _rows_times(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a [N, K] @ b [K, M] -> [N, M], chunked over the rows."""
    from trase.threads import numba_threads

    kernels = _products()
    out = np.empty((a.shape[0], b.shape[1]), dtype=a.dtype)
    with numba_threads() as n:
        if n > 1:
            kernels.rows_times(a, b, out)
        else:
            kernels.on_this_thread(kernels.rows_chunk, a.shape[0], a, b, out)
    return out


def _transposed_times(g: np.ndarray, x: np.ndarray) -> np.ndarray:
    """g [N, O]^T @ x [N, I] -> [O, I], summed over the row chunks in their order."""
    from trase.threads import numba_threads

    kernels = _products()
    partial = np.empty((kernels.n_chunks(g.shape[0]), g.shape[1], x.shape[1]), dtype=g.dtype)
    with numba_threads() as n:
        if n > 1:
            kernels.transposed_times(g, x, partial)
        else:
            kernels.on_this_thread(kernels.transposed_chunk, g.shape[0], g, x, partial)
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
