"""The reconstruction's presets, declared as data: each CPU preset changes what it says it
changes, on the rig it says."""

import dataclasses

import pytest

from lazyspecs.presets import Context
from trase.reconstruction_config import ReconstructionConfig
from trase.reconstruction_presets import RECONSTRUCTION_PRESETS, cpu_train_downscale
from trase.reconstruction_presets import reconstruction_preset as preset


def declared(name: str) -> set[str]:
    """The fields preset ``name``'s own declarations set (on any rig)."""
    return {k for d in RECONSTRUCTION_PRESETS.preset(name).declarations for k in d.values}


def test_cpu_preset_keeps_the_long_lr_decay_for_any_run_length():
    v1 = preset("cpu-v1")
    assert v1.iterations == 2000 and v1.densify_until == 1500 and v1.warm_up == 300 and v1.torch_threads == 1
    v2 = preset("cpu-v2")
    changed = {k for k, v in dataclasses.asdict(v2).items() if v != getattr(v1, k)}
    assert changed == declared("cpu-v2")
    v3 = preset("cpu-v3")  # a monocular capture
    changed = {k for k, v in dataclasses.asdict(v3).items() if v != getattr(v2, k)}
    assert changed == declared("cpu-v3")
    # the same schedule over twice the iterations: every step point doubled
    for k in declared("cpu-v3"):
        assert getattr(v3, k) == 2 * getattr(v2, k), k
    assert (v3.iterations, v3.position_lr_max_steps) == (4000, 20_000)
    v4 = preset("cpu-v4")
    changed = {k for k, v in dataclasses.asdict(v4).items() if v != getattr(v3, k)}
    assert changed == declared("cpu-v4") == {"min_opacity"}
    assert v4.min_opacity == 0.1 and v3.min_opacity == 0.005
    # a multi-view rig kept cpu_v2's settings under cpu_v3 and cpu_v4
    assert preset("cpu-v4", monocular=False) == preset("cpu-v3", monocular=False) == v2
    # the cpu preset: cpu_v4 on a monocular capture; a multi-view rig gets the monocular
    # schedule (4000 iterations), not its pruning
    assert preset("cpu") == v4
    multi = preset("cpu", monocular=False)
    changed = {k for k, v in dataclasses.asdict(multi).items() if v != getattr(v2, k)}
    assert changed == declared("cpu") == declared("cpu-v3")
    assert multi == dataclasses.replace(v3, min_opacity=v2.min_opacity) and multi.min_opacity == 0.005
    assert multi.iterations == 4000
    short = preset("cpu-v2", iterations=2000)
    # the runner's 2000 steps: learning rates still decay over 20000 steps (annealing inside a
    # short run cost 1.2-1.7 dB), the densification/warm-up points are not rescaled
    assert (short.position_lr_max_steps, short.deform_lr_max_steps) == (20_000, 20_000)
    assert (short.warm_up, short.densify_until, short.time_noise_steps) == (300, 1500, 2000)
    assert preset("cpu", iterations=2000, position_lr_max_steps=2000).position_lr_max_steps == 2000
    assert preset("cpu", iterations=2000).warm_up == 600  # an override changes that setting alone


def test_presets_name_their_densification_statistic():
    assert ReconstructionConfig.paper().densify_statistic == "means2d"  # 3DGS's statistic
    assert preset("cpu").densify_statistic == "lstsq"  # what the cpu presets were tuned with
    assert preset("cpu-v1").densify_statistic == "lstsq"
    assert preset("cpu-v2").densify_statistic == "lstsq"


def test_presets_name_their_near_plane():
    assert ReconstructionConfig.paper().near_plane == 0.2  # the public rasterizer culls p_view.z <= 0.2
    for name in ("cpu", "cpu-v1", "cpu-v2", "cpu-v4"):
        assert preset(name).near_plane == 0.01  # what the cpu presets were measured with
    for bad in (0.0, -0.2, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="near_plane"):
            ReconstructionConfig(near_plane=bad)


def test_the_paper_preset_is_the_configs_defaults_and_cpu_presets_are_in_the_cpu_tier():
    assert preset("paper") == ReconstructionConfig()
    assert [RECONSTRUCTION_PRESETS.preset(n).tier for n in RECONSTRUCTION_PRESETS.names()] == ["paper"] + ["cpu"] * 5


def test_the_training_scale_follows_the_image_size_and_every_value_says_where_it_was_declared():
    r = RECONSTRUCTION_PRESETS.resolve("cpu", Context(monocular=True, image_size=(960, 536)))
    assert r.config.image_downscale == 2.0 == cpu_train_downscale((960, 536))
    assert r.sources["iterations"].endswith("(monocular)") and "reconstruction_presets.py:" in r.sources["iterations"]
    assert r.sources["lambda_dssim"] == "default (ReconstructionConfig)"
    multi = RECONSTRUCTION_PRESETS.resolve("cpu", Context(monocular=False))
    assert multi.sources["iterations"].endswith("(multi-view)") and multi.sources["min_opacity"] == "default (ReconstructionConfig)"
    with pytest.raises(LookupError, match="unknown reconstruction preset 'gpu'; known: paper, cpu-v1"):
        preset("gpu")
