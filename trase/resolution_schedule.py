"""Resolution and primitive schedules of the reconstruction: render the training views small
while the optimisation fits their low frequencies, and grow the gaussian count with the
resolution instead of densifying to the cap early (or with the resolution the spectrum asks
for, while the views render at full size).

The idea is DashGaussian's (CVPR 2025), written anew here: an image's spectral energy sits
mostly at low frequencies, so the first iterations need few pixels. The schedule is set by the
training images' own spectrum. ``energy(f)`` is the share of their spectral energy (gray, mean
removed) that an image downscaled by ``f`` still holds, i.e. the energy inside the frequency band
``|fx| <= W / (2 f)``, ``|fy| <= H / (2 f)``. At progress ``p`` (iteration / ``until``) the
schedule takes the largest factor whose energy reaches ``energy(max) + (1 - energy(max)) p``:
the energy the renders can show rises linearly from the smallest size's to all of it, and the
views are rendered at full size from ``until`` on. The primitive schedule caps the gaussian count at
``max_gaussians / f**2`` (at least the count training started from), the pixels' share.

The densification statistic is the screen-space gradient in NDC units
(``trase.densify.screen_grad_norm``), which does not depend on the render's size, so the
thresholds stay as configured.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import torch

# What the schedule's code computes for the same settings; bumped when that changes, so results
# of older code are not reused. 2: a downscaled view's camera is scaled by its rounded size.
SCHEDULE_VERSION = 2
FACTOR_STEP = 0.25  # the candidate downscale factors: 1, 1.25, 1.5, ... up to the maximum
MIN_SIDE = 16  # px: no factor renders a view smaller than this on its short side


def candidate_factors(max_factor: float, width: int, height: int) -> list[float]:
    """Downscale factors 1, 1 + FACTOR_STEP, ... up to ``max_factor`` and to a short side of
    MIN_SIDE px, ascending."""
    limit = min(float(max_factor), min(width, height) / MIN_SIDE)
    n = max(math.floor((limit - 1.0) / FACTOR_STEP + 1e-9), 0)
    return [1.0 + FACTOR_STEP * k for k in range(n + 1)]


def band_energy(images: Sequence[torch.Tensor], factors: Sequence[float]) -> list[float]:
    """The mean over ``images`` ([H, W, 3] in [0, 1]) of the share of each one's spectral energy
    (gray, mean removed) inside the band a downscale by each of ``factors`` keeps. 1 for a flat
    image (nothing to lose)."""
    shares = np.zeros(len(factors))
    for img in images:
        gray = np.asarray(img.detach().cpu(), dtype=np.float64).mean(axis=2)
        h, w = gray.shape
        power = np.abs(np.fft.fft2(gray - gray.mean())) ** 2  # [H, W]
        total = power.sum()
        fy = np.abs(np.fft.fftfreq(h))[:, None] * h  # cycles per image height
        fx = np.abs(np.fft.fftfreq(w))[None, :] * w
        for k, f in enumerate(factors):
            inside = (fy <= h / (2 * f)) & (fx <= w / (2 * f))
            shares[k] += 1.0 if total <= 0 else float(power[inside].sum() / total)
    return [float(s / max(len(images), 1)) for s in shares]


@dataclasses.dataclass
class ResolutionSchedule:
    """The downscale factor of each iteration (``factor_at``) and the gaussian cap that goes
    with it (``cap_at``)."""

    factors: list[float]  # ascending, factors[0] == 1
    energy: list[float]  # band_energy of each factor: descending, energy[0] == 1
    until: int  # the iteration from which views render at full size
    grow_primitives: bool = False
    max_gaussians: int = 0  # the configured cap (0: none)
    start_gaussians: int = 0  # the count training started from: the cap never goes below it

    def factor_at(self, it: int) -> float:
        """The largest factor whose energy reaches the share the progress ``it / until`` asks."""
        if self.until <= 0 or it >= self.until or len(self.factors) == 1:
            return 1.0
        lowest = self.energy[-1]
        wanted = lowest + (1.0 - lowest) * max(it, 0) / self.until
        fitting = [f for f, e in zip(self.factors, self.energy) if e >= wanted - 1e-12]
        return max(fitting) if fitting else 1.0

    def cap_at(self, it: int) -> int:
        """The gaussian cap at iteration ``it``: the configured one, or with the primitive
        schedule its share of the pixels the views render at (0: no cap)."""
        if not self.grow_primitives or self.max_gaussians <= 0:
            return self.max_gaussians
        f = self.factor_at(it)
        return max(int(self.max_gaussians / (f * f)), min(self.start_gaussians, self.max_gaussians))


def make_schedule(images: Sequence[torch.Tensor], width: int, height: int, max_factor: float, until: int,
                  grow_primitives: bool = False, max_gaussians: int = 0, start_gaussians: int = 0,
                  sample: int = 16) -> ResolutionSchedule:
    """The schedule for these training images (at most ``sample`` of them, evenly spread, are
    read for the spectrum)."""
    factors = candidate_factors(max_factor, width, height)
    step = max(1, len(images) // max(sample, 1))
    energy = band_energy(list(images)[::step][:sample], factors)
    energy = [float(e) for e in np.minimum.accumulate(energy)]  # a coarser band never holds more energy
    energy[0] = 1.0
    return ResolutionSchedule(factors, energy, int(until), grow_primitives, int(max_gaussians), int(start_gaussians))


def downscaled(image: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """[H, W, 3] -> [height, width, 3] by area averaging (the mean of the pixels each covers)."""
    if image.shape[0] == height and image.shape[1] == width:
        return image
    x = image.permute(2, 0, 1)[None]  # [1, 3, H, W]
    out = torch.nn.functional.interpolate(x, size=(height, width), mode="area")
    return out[0].permute(1, 2, 0).contiguous()



class ScaledViews:
    """The training views (a ``trase.training_images.ImageCache``) at each iteration's size under
    ``schedule``: the camera scaled and the image area-averaged, cached per view and factor."""

    def __init__(self, data, schedule: ResolutionSchedule) -> None:
        self.data, self.schedule = data, schedule
        self._cache: dict[tuple[int, float], tuple] = {}

    def view(self, index: int, it: int):
        """(camera, image [h, w, 3]) of training view ``index`` at iteration ``it``."""
        f = self.schedule.factor_at(it)
        if f == 1.0:
            return self.data.cameras[index], self.data.images[index]
        key = (index, f)
        if key not in self._cache:
            cam = self.data.cameras[index].scaled(f)
            self._cache[key] = (cam, downscaled(self.data.images[index], cam.width, cam.height))
        return self._cache[key]


def config_schedule(data, cfg, start_gaussians: int) -> ResolutionSchedule | None:
    """The schedule ``cfg`` (a ReconstructionConfig) asks of these training views: for the
    rendered size, the gaussian cap or both; None where neither schedule is on."""
    if (cfg.resolution_schedule == "off" and cfg.primitive_schedule == "off") or not len(data.images):
        return None
    cam = data.cameras[0]
    return make_schedule(data.images, cam.width, cam.height, cfg.resolution_max_factor,
                         cfg.resolution_until or cfg.densify_until, cfg.primitive_schedule != "off",
                         cfg.max_gaussians, start_gaussians)


def scaled_views(data, cfg, schedule: ResolutionSchedule | None) -> ScaledViews | None:
    """The views at each iteration's size under ``schedule``, None where ``cfg`` renders them at
    full size throughout (the resolution schedule off)."""
    if cfg.resolution_schedule == "off" or schedule is None:
        return None
    return ScaledViews(data, schedule)


__all__ = ["SCHEDULE_VERSION", "ResolutionSchedule", "ScaledViews", "band_energy", "candidate_factors", "config_schedule",
           "downscaled", "make_schedule", "scaled_views"]
