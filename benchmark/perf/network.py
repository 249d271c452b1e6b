"""The deformation network's training step on this machine: milliseconds and GFLOP/s against
the rate of one of its matrix products alone.

On the CPU the network is most of a reconstruction step (docs/notes/skip.md), and its cost is
per gaussian. This suite says how close the step already runs to what the cores can do: the
step is the network's forward and backward as training runs it (the canonical means detached,
gradients for every weight; ``trase.deformation.DeformMLP``), the product is ``[N, W] @ [W, W]``,
the shape of its hidden layers, timed 20 in a row. The flops are counted from the layers' shapes
(``step_flops``), so the ratio is the share of the product's rate the whole step reaches. Each
case runs with both engines of the network's products (``trase.blas_linear``: torch's, and
OpenBLAS's in row chunks, which portable numerics use), one after the other in this process.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import torch

from benchmark.perf.common import fmt, load_average, stats, table, time_repeats, versions

QUICK = {"cases": [("small", 2_000)], "repeats": 3}
DEFAULT = {"cases": [("small", 5_000), ("small", 15_000), ("small", 50_000), ("paper", 15_000)], "repeats": 15}


def step_flops(net, n: int) -> int:
    """Floating-point operations (2 per multiply-add) of one training step of ``net`` (a
    DeformMLP) on ``n`` gaussians whose means are detached. Forward: every layer's per-gaussian
    columns (the time encoding's are one row, computed once per call) times its outputs. Backward:
    the weights' gradients cost as much again; the hidden inputs' gradients cost each layer's
    hidden columns times its outputs; the encoded means get none (they are detached)."""
    t_ch = (net.time_out if net.blender else 1 + 2 * net.t_freqs)
    heads = (net.gaussian_warp, net.gaussian_rotation, net.gaussian_scaling)
    forward = hidden_grads = 0
    for i, layer in enumerate(net.linear):
        reads_input = i == 0 or i == net.skip + 1
        per_row = layer.in_features - (t_ch if reads_input else 0)
        forward += layer.out_features * per_row
        if i > 0:
            hidden_grads += layer.out_features * net.W
    for head in heads:
        forward += head.out_features * head.in_features
        hidden_grads += head.out_features * head.in_features
    return 2 * n * (2 * forward + hidden_grads)


def training_step(net, xyz: torch.Tensor, grads: list[torch.Tensor]) -> Callable[[], None]:
    """One forward + backward of ``net`` at t = 0.5, the offsets' gradients given."""

    def step() -> None:
        net.zero_grad(set_to_none=True)
        torch.autograd.backward(net(xyz, 0.5), grads)

    return step


def measure(preset: str, n: int, repeats: int, products: str) -> dict:
    """The step, the forward alone and the hidden layers' product for one network, count and
    engine of the products (``trase.blas_linear.ENGINES``)."""
    from trase import blas_linear

    previous = blas_linear.set_engine(products)
    try:
        return {**_measure(preset, n, repeats, blas_linear.linear), "products": products}
    finally:
        blas_linear.set_engine(previous)


def _measure(preset: str, n: int, repeats: int, linear: Callable) -> dict:
    from trase.deformation import DeformMLP

    gen = torch.Generator().manual_seed(0)
    net = DeformMLP.preset(preset)
    xyz = torch.rand(n, 3, generator=gen) * 2 - 1  # [n, 3] canonical means, detached
    grads = [torch.randn(n, k, generator=gen) for k in (3, 4, 3)]  # d_xyz, d_rot, d_scale
    step_s, _ = time_repeats(training_step(net, xyz, grads), repeats, warmup=2)

    def forward() -> None:
        with torch.no_grad():
            net(xyz, 0.5)

    forward_s, _ = time_repeats(forward, repeats, warmup=1)
    a, w = torch.randn(n, net.W, generator=gen), torch.randn(net.W, net.W, generator=gen)  # [n, W], [W, W]
    per_repeat = 20  # products per timed repeat: the rate of a steady run of them, as in the step
    with torch.no_grad():
        batches, _ = time_repeats(lambda: [linear(a, w) for _ in range(per_repeat)], repeats, warmup=1)
    product_s = stats([t / per_repeat for t in batches["all"]])  # seconds per product
    flops = step_flops(net, n)
    step_rate = flops / step_s["median"] / 1e9
    product_rate = 2 * n * net.W * net.W / product_s["median"] / 1e9
    return {"preset": preset, "depth": net.D, "width": net.W, "gaussians": n, "step_seconds": step_s,
            "forward_seconds": forward_s, "product_seconds": product_s, "step_gflop": flops / 1e9,
            "step_gflops_per_s": step_rate, "product_gflops_per_s": product_rate,
            "share_of_product_rate": step_rate / product_rate}


def run(quick: bool = False, echo: Callable[[str], None] = print) -> dict:
    cfg = QUICK if quick else DEFAULT
    echo(f"The deformation network's training step (forward + backward, means detached) and a "
         f"[N, W] @ [W, W] product alone; median of {cfg['repeats']} (spread = max - min), "
         f"{torch.get_num_threads()} torch threads")
    results, rows = [], []
    from trase import blas_linear

    for (preset, n), products in itertools.product(cfg["cases"], blas_linear.ENGINES):
        r = measure(preset, n, cfg["repeats"], products)
        results.append(r)
        rows.append([f"{preset} ({r['depth']}x{r['width']}), {n:,} gaussians", products, fmt(r["step_seconds"]),
                     fmt(r["forward_seconds"]), f"{r['step_gflop']:.3f}", f"{r['step_gflops_per_s']:.0f}",
                     f"{r['product_gflops_per_s']:.0f}", f"{r['share_of_product_rate']:.2f}"])
    echo(table(rows, ["network, gaussians", "products", "step", "forward", "GFLOP", "GFLOP/s", "product GFLOP/s",
                      "share"]))
    return {
        "description": __doc__.strip().splitlines()[0],
        "quick": quick,
        "settings": {**cfg, "torch_threads": torch.get_num_threads(), "engine_of_this_process": blas_linear.engine()},
        "versions": versions("torch"),
        "cases": results,
        "load_average_end": load_average(),
    }
