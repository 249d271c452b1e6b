"""The resolution and primitive schedules (trase.resolution_schedule): factors from the images'
spectrum, the size and cap of each iteration, area downscaling, and a reconstruction under them."""

import dataclasses
import itertools
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from recon_scene import write_scene

from trase.camera import Camera, intrinsics
from trase.reconstruct import reconstruct
from trase.reconstruction_config import ReconstructionConfig
from trase.reconstruction_presets import reconstruction_preset
from trase.resolution_schedule import (
    ResolutionSchedule,
    ScaledViews,
    band_energy,
    candidate_factors,
    config_schedule,
    downscaled,
    make_schedule,
    scaled_views,
)


def test_candidate_factors_stop_at_the_maximum_and_at_the_smallest_side():
    assert candidate_factors(2.0, 160, 120) == [1.0, 1.25, 1.5, 1.75, 2.0]
    assert candidate_factors(4.0, 40, 30) == [1.0, 1.25, 1.5, 1.75]  # 30 / 16 px
    assert candidate_factors(4.0, 16, 16) == [1.0]


def test_a_smooth_image_keeps_its_energy_when_downscaled_and_a_fine_pattern_does_not():
    y, x = np.mgrid[0:64, 0:64]
    smooth = torch.from_numpy(np.repeat((0.5 + 0.4 * np.sin(2 * np.pi * x / 64))[..., None], 3, axis=2))
    checker = torch.from_numpy(np.repeat((((x + y) % 2) * 1.0)[..., None], 3, axis=2))
    flat = torch.full((64, 64, 3), 0.3)
    assert band_energy([smooth], [1.0, 4.0]) == pytest.approx([1.0, 1.0])
    assert band_energy([checker], [1.0, 2.0]) == pytest.approx([1.0, 0.0], abs=1e-9)
    assert band_energy([flat], [1.0, 4.0]) == [1.0, 1.0]  # nothing to lose


def test_the_size_rises_to_full_at_until_and_the_cap_grows_with_it():
    s = ResolutionSchedule([1.0, 2.0, 4.0], [1.0, 0.9, 0.8], until=1000, grow_primitives=True,
                           max_gaussians=16000, start_gaussians=500)
    factors = [s.factor_at(it) for it in range(0, 1200, 50)]
    assert factors[0] == 4.0 and all(a >= b for a, b in itertools.pairwise(factors)) and s.factor_at(1000) == 1.0
    assert s.factor_at(400) == 2.0  # wanted 0.88: the 2x band holds 0.9
    assert s.cap_at(0) == 1000 and s.cap_at(400) == 4000 and s.cap_at(1000) == 16000
    assert dataclasses.replace(s, start_gaussians=3000).cap_at(0) == 3000  # never below the start
    assert dataclasses.replace(s, grow_primitives=False).cap_at(0) == 16000


def test_area_downscaling_averages_the_pixels_each_covers():
    img = torch.arange(16, dtype=torch.float32).reshape(4, 4, 1).repeat(1, 1, 3)
    small = downscaled(img, 2, 2)
    assert small[..., 0].tolist() == [[2.5, 4.5], [10.5, 12.5]] and downscaled(img, 4, 4) is img


def test_the_settings_are_checked():
    with pytest.raises(ValueError, match="resolution_schedule must be one of"):
        ReconstructionConfig(resolution_schedule="dash")
    with pytest.raises(ValueError, match="needs a resolution_schedule"):
        ReconstructionConfig(primitive_schedule="resolution")
    with pytest.raises(ValueError, match="primitive_schedule one of"):
        ReconstructionConfig(primitive_schedule="dash")
    with pytest.raises(ValueError, match="resolution_max_factor must be >= 1"):
        ReconstructionConfig(resolution_max_factor=0.5)


def test_a_reconstruction_under_the_schedules_trains_small_first_and_keeps_to_the_cap(tmp_path):
    views, pts, _, _ = write_scene(tmp_path / "images", num=6, size=64)
    cfg = reconstruction_preset("cpu", iterations=40, warm_up=15, densify_from=10, densify_until=35,
                                densify_interval=10, checkpoint_interval=40, time_noise_steps=40,
                                position_lr_max_steps=40, deform_lr_max_steps=40, max_gaussians=len(pts) + 40,
                                resolution_schedule="frequency", primitive_schedule="resolution")
    g, _ = reconstruct(views, pts, None, cfg, tmp_path / "m", progress=False)
    assert g.num_gaussians <= cfg.max_gaussians
    from trase.training_images import ImageCache

    data = ImageCache(views, 1.0, np.zeros(3, np.float32))
    schedule = make_schedule(data.images, 64, 64, cfg.resolution_max_factor, cfg.densify_until)
    assert schedule.factor_at(0) > 1.0 and schedule.factor_at(35) == 1.0


def test_a_scaled_view_camera_fits_its_image_when_the_size_is_rounded():
    cam = Camera(K=intrinsics(150.0, 150.0, 80.0, 60.0), w2c=np.eye(4), width=160, height=120)
    data = SimpleNamespace(cameras=[cam], images=[torch.rand(120, 160, 3)])
    schedule = ResolutionSchedule([1.0, 2.75], [1.0, 0.5], until=10)
    small, image = ScaledViews(data, schedule).view(0, 0)
    assert image.shape == (small.height, small.width, 3) == (44, 58, 3)  # 120 / 2.75 = 43.6, 160 / 2.75 = 58.2
    corner = np.array([[160.0, 120.0]])  # the full image's bottom-right corner, in pixels
    np.testing.assert_allclose(corner * [small.width / 160, small.height / 120],
                               [[small.K[0, 0] * (160 - 80) / 150 + small.K[0, 2],
                                 small.K[1, 1] * (120 - 60) / 150 + small.K[1, 2]]], atol=1e-9)


def test_the_frequency_cap_grows_with_the_spectrum_while_the_views_render_at_full_size():
    """primitive_schedule "frequency" without a resolution schedule: the cap follows the sizes the
    spectrum asks for, the views stay full size; with both schedules off there is no schedule."""
    rng = np.random.default_rng(0)
    cam = Camera(K=intrinsics(60.0, 60.0, 32.0, 32.0), w2c=np.eye(4), width=64, height=64)
    data = SimpleNamespace(cameras=[cam] * 3, images=[torch.from_numpy(rng.random((64, 64, 3), dtype=np.float32))] * 3)
    cfg = ReconstructionConfig(primitive_schedule="frequency", max_gaussians=1000, densify_until=100)
    schedule = config_schedule(data, cfg, start_gaussians=50)
    assert schedule is not None and scaled_views(data, cfg, schedule) is None
    assert 50 <= schedule.cap_at(0) < 1000 and schedule.cap_at(100) == 1000
    assert [schedule.cap_at(i) for i in range(0, 101, 10)] == sorted(schedule.cap_at(i) for i in range(0, 101, 10))
    both = dataclasses.replace(cfg, resolution_schedule="frequency")
    assert config_schedule(data, both, 50).cap_at(0) == schedule.cap_at(0) and scaled_views(data, both, schedule) is not None
    assert config_schedule(data, ReconstructionConfig(max_gaussians=1000), 50) is None


def test_a_reconstruction_under_the_frequency_cap_alone_keeps_below_it(tmp_path):
    views, pts, _, _ = write_scene(tmp_path / "images", num=6, size=64)
    early = {}
    for rule in ("off", "frequency"):  # 20 iterations of a schedule whose cap reaches full at 35
        cfg = reconstruction_preset("cpu", iterations=20, warm_up=15, densify_from=10, densify_until=35,
                                    densify_interval=10, checkpoint_interval=20, time_noise_steps=20,
                                    position_lr_max_steps=40, deform_lr_max_steps=40, max_gaussians=len(pts) + 400,
                                    densify_grad_threshold=1e-9, primitive_schedule=rule)
        g, _ = reconstruct(views, pts, None, cfg, tmp_path / f"m-{rule}", progress=False)
        early[rule] = g.num_gaussians
    assert early["frequency"] < early["off"] <= len(pts) + 400
