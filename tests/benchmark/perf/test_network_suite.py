"""The network suite's flop count against torch's own count of the products a step runs."""

import pytest
import torch
from torch.utils.flop_counter import FlopCounterMode

from benchmark.perf.network import step_flops, training_step
from trase import blas_linear
from trase.deformation import DeformMLP


def counted_flops(net, n: int) -> int:
    """torch's count of the step's products (torch's engine: it does not see OpenBLAS's)."""
    gen = torch.Generator().manual_seed(0)
    xyz = torch.rand(n, 3, generator=gen)
    grads = [torch.randn(n, k, generator=gen) for k in (3, 4, 3)]
    previous = blas_linear.set_engine("torch")
    try:
        with FlopCounterMode(display=False) as counter:
            training_step(net, xyz, grads)()
    finally:
        blas_linear.set_engine(previous)
    return counter.get_total_flops()


@pytest.mark.parametrize("net", [DeformMLP.preset("small"), DeformMLP(D=6, W=32), DeformMLP(D=4, W=16, blender=True)],
                         ids=["small", "6x32", "blender"])
def test_step_flops_per_gaussian_match_torch_count(net):
    # the time encoding's row costs the same at any count, so compare what 100 more gaussians add
    assert counted_flops(net, 200) - counted_flops(net, 100) == step_flops(net, 200) - step_flops(net, 100)
    assert step_flops(net, 100) > 0


def test_quick_run_reports_rates():
    from benchmark.perf import network

    out = network.run(quick=True, echo=lambda s: None)
    assert [c["products"] for c in out["cases"]] == ["torch", "openblas"]  # both engines, side by side
    case = out["cases"][1]
    assert case["gaussians"] == 2_000 and case["step_seconds"]["median"] > 0
    assert case["step_gflop"] == pytest.approx(step_flops(DeformMLP.preset("small"), 2_000) / 1e9)
    assert case["share_of_product_rate"] == pytest.approx(case["step_gflops_per_s"] / case["product_gflops_per_s"])
