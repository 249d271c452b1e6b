"""The reconstruction's typed config and schedules."""

import numpy as np
import pytest

from trase.reconstruction_config import ReconstructionConfig, expon_lr


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
