"""The reconstruction's presets and schedules."""

import dataclasses

import numpy as np
import pytest

from trase.reconstruction_config import (
    CPU_CHANGES,
    CPU_MONOCULAR_PRUNING,
    CPU_MONOCULAR_SCHEDULE,
    CPU_MULTIVIEW_SCHEDULE,
    ReconstructionConfig,
    expon_lr,
)


def test_presets_and_schedule():
    cfg = ReconstructionConfig.paper(warm_up=1500, densify_until=9000)
    assert (cfg.warm_up, cfg.densify_until) == (1500, 9000)
    assert cfg.deform_preset == "paper" and cfg.lambda_dssim == 0.2
    # the public TRASE code's defaults, not Deformable-3DGS's (0.0007, 0.001)
    assert (cfg.densify_grad_threshold, cfg.scaling_lr) == (0.0002, 0.005)
    with pytest.raises(TypeError):
        ReconstructionConfig.paper(no_such_setting=1)
    assert expon_lr(0, 1e-3, 1e-5, 100) == pytest.approx(1e-3)
    assert expon_lr(100, 1e-3, 1e-5, 100) == pytest.approx(1e-5)
    assert expon_lr(50, 1e-3, 1e-5, 100) == pytest.approx(1e-4)
    assert np.isfinite(expon_lr(10**9, 1e-3, 1e-5, 100))


def test_cpu_preset_keeps_the_long_lr_decay_for_any_run_length():
    v1 = ReconstructionConfig.cpu_v1()
    assert v1.iterations == 2000 and v1.densify_until == 1500 and v1.warm_up == 300 and v1.torch_threads == 1
    v2 = ReconstructionConfig.cpu_v2()
    changed = {k for k, v in dataclasses.asdict(v2).items() if v != getattr(v1, k)}
    assert changed == set(CPU_CHANGES)
    v3 = ReconstructionConfig.cpu_v3()  # a monocular capture
    changed = {k for k, v in dataclasses.asdict(v3).items() if v != getattr(v2, k)}
    assert changed == set(CPU_MONOCULAR_SCHEDULE)
    # the same schedule over twice the iterations: every step point doubled
    for k in CPU_MONOCULAR_SCHEDULE:
        assert getattr(v3, k) == 2 * getattr(v2, k), k
    assert (v3.iterations, v3.position_lr_max_steps) == (4000, 20_000)
    v4 = ReconstructionConfig.cpu_v4()
    changed = {k for k, v in dataclasses.asdict(v4).items() if v != getattr(v3, k)}
    assert changed == set(CPU_MONOCULAR_PRUNING) == {"min_opacity"}
    assert v4.min_opacity == 0.1 and v3.min_opacity == 0.005
    # a multi-view rig kept cpu_v2's settings under cpu_v3 and cpu_v4
    assert ReconstructionConfig.cpu_v4(monocular=False) == ReconstructionConfig.cpu_v3(monocular=False) == v2
    # the cpu preset: cpu_v4 on a monocular capture; a multi-view rig gets the monocular
    # schedule (4000 iterations), not its pruning
    assert ReconstructionConfig.cpu() == v4
    multi = ReconstructionConfig.cpu(monocular=False)
    changed = {k for k, v in dataclasses.asdict(multi).items() if v != getattr(v2, k)}
    assert changed == set(CPU_MULTIVIEW_SCHEDULE) == set(CPU_MONOCULAR_SCHEDULE)
    assert multi == dataclasses.replace(v3, min_opacity=v2.min_opacity) and multi.min_opacity == 0.005
    assert multi.iterations == 4000
    short = ReconstructionConfig.cpu_v2(iterations=2000)
    # the runner's 2000 steps: learning rates still decay over 20000 steps (annealing inside a
    # short run cost 1.2-1.7 dB), the densification/warm-up points are not rescaled
    assert (short.position_lr_max_steps, short.deform_lr_max_steps) == (20_000, 20_000)
    assert (short.warm_up, short.densify_until, short.time_noise_steps) == (300, 1500, 2000)
    assert ReconstructionConfig.cpu(iterations=2000, position_lr_max_steps=2000).position_lr_max_steps == 2000
    assert ReconstructionConfig.cpu(iterations=2000).warm_up == 600  # an override changes that setting alone


def test_presets_name_their_densification_statistic():
    assert ReconstructionConfig.paper().densify_statistic == "means2d"  # 3DGS's statistic
    assert ReconstructionConfig.cpu().densify_statistic == "lstsq"  # what the cpu presets were tuned with
    assert ReconstructionConfig.cpu_v1().densify_statistic == "lstsq"
    assert ReconstructionConfig.cpu_v2().densify_statistic == "lstsq"
