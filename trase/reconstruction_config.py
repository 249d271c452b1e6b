"""Settings of the dynamic reconstruction: the typed config (its defaults are the public TRASE
code's, the ``paper`` preset) and the learning-rate and time-noise schedules. The presets, and
why each value in them was chosen: trase.reconstruction_presets."""

from __future__ import annotations

import dataclasses
import math
import re

DENSIFY_STATISTICS = ("means2d", "lstsq")
RESOLUTION_SCHEDULES = ("off", "frequency")  # trase.resolution_schedule
PRIMITIVE_SCHEDULES = ("off", "resolution", "frequency")
DEFORM_PRESETS = {"paper": (8, 256), "small": (4, 64)}  # name -> (depth D, width W)


def deform_shape(name: str) -> tuple[int, int]:
    """(D, W) of a deformation preset name: one of DEFORM_PRESETS or ``<D>x<W>``."""
    if name in DEFORM_PRESETS:
        return DEFORM_PRESETS[name]
    m = re.fullmatch(r"(\d+)x(\d+)", str(name))
    if m is None or int(m.group(1)) < 2 or int(m.group(2)) < 1:
        raise ValueError(f"unknown deformation preset {name!r} (use {', '.join(map(repr, DEFORM_PRESETS))} "
                         "or '<depth>x<width>' with depth >= 2, e.g. '8x128')")
    return int(m.group(1)), int(m.group(2))


@dataclasses.dataclass
class ReconstructionConfig:
    iterations: int = 20_000
    warm_up: int = 3_000  # iterations without deformation
    # learning rates (Deformable-3DGS): positions and the deform net decay exponentially
    position_lr_init: float = 0.00016
    position_lr_final: float = 0.0000016
    position_lr_max_steps: int = 30_000
    deform_lr_max_steps: int = 40_000
    spatial_lr_scale: float = 5.0
    feature_lr: float = 0.0025  # SH DC; higher bands use feature_lr / 20
    opacity_lr: float = 0.05
    scaling_lr: float = 0.005  # the public TRASE code (Deformable-3DGS: 0.001)
    rotation_lr: float = 0.001
    # densification
    percent_dense: float = 0.01
    densify_from: int = 500
    densify_until: int = 15_000
    densify_interval: int = 100
    densify_grad_threshold: float = 0.0002  # the public TRASE code (Deformable-3DGS: 0.0007)
    # the densification statistic: "means2d" is 3DGS's, the gradient of the rendered screen
    # positions (RenderOutput.means2d); "lstsq" recovers it from the gradient of the 3D means by
    # least squares through the projection Jacobian (it also carries what reaches a mean
    # through its 2D covariance), what this trainer used before renders returned projection data
    densify_statistic: str = "means2d"
    min_opacity: float = 0.005
    opacity_reset_interval: int = 3_000
    max_gaussians: int = 0  # 0 = no cap
    # render the training views small while the low frequencies are fitted
    # (trase.resolution_schedule): "off" (the public code), or "frequency": the size follows the
    # training images' spectrum, from at most resolution_max_factor x smaller up to full size at
    # resolution_until (0: densify_until)
    resolution_schedule: str = "off"
    resolution_max_factor: float = 4.0
    resolution_until: int = 0
    # the gaussian cap growing with the detail fitted: "resolution" (with a resolution schedule)
    # caps the count at max_gaussians x the share of pixels rendered; "frequency" at the share
    # the frequency schedule would render (resolution_max_factor, resolution_until) whether or
    # not the views render small; "off": the configured cap throughout
    primitive_schedule: str = "off"
    # appearance
    sh_degree: int = 3
    sh_interval: int = 1_000  # one more SH band every this many iterations
    lambda_dssim: float = 0.2
    white_background: bool = False
    # solid surfaces: weight of the mean binary entropy of the opacities (0 = off, the public
    # code), added to the loss from iteration opacity_entropy_from; it drives every opacity to
    # 0 or 1, so an object rendered alone has no see-through patches
    opacity_entropy_weight: float = 0.0
    opacity_entropy_from: int = 0
    # deformation
    deform_preset: str = "paper"  # "paper" (D=8, W=256), "small" (D=4, W=64) or "<D>x<W>"
    deform_zero_init: bool = False  # start as the identity (see DeformMLP.zero_heads)
    # how d_scale is applied (trase.deformation.offset_scales): "mirror" |s + d| is the public
    # code's (its rasterizer squares the scale); "clamp" floors s + d, the rule the cpu presets
    # were tuned with
    deform_scale_rule: str = "mirror"
    # the rasterizer's near plane while training (view-space depth, scene units): gaussians
    # closer to the camera are not drawn and get no gradient. 0.2 is the public code's (3DGS's
    # rasterizer culls p_view.z <= 0.2); the cpu presets keep the 0.01 they were measured with.
    # Close to the plane a gaussian's screen position moves as 1 / z^2 with its depth: what the
    # network's offsets receive from one drawn there is hundreds of times larger at 0.01
    near_plane: float = 0.2
    # the network's gradients only for gaussians in view (deformation.deformed_visible): the
    # same images and gradients up to rounding; no effect on a GPU. Off by default: it pays
    # only when a camera sees a small part of the scene. Measured on the synthetic HyperNeRF
    # scene (30k gaussians, 80-85% of them in view): 353 ms per step against 302 ms without.
    deform_visible_only: bool = False
    # static gaussians skip the network (trase.static_gaussians): from warm_up + static_from,
    # every static_interval iterations, gaussians whose centre, size and surface move less than
    # static_threshold x the scene extent over the scene's times are frozen at their mean
    # offsets and the network runs for the others only;
    # a gaussian whose motion rises again is woken up. 0 = off (the public code)
    static_threshold: float = 0.0
    static_from: int = 1_000
    static_interval: int = 500
    # nothing new freezes at a check while the training views of the worst of its times lie
    # more than static_time_gap dB below the median time's (a motion not learned yet; 0 = off)
    static_time_gap: float = 0.0
    # with static_time_gap, where a check's gap exceeds it: > 0 holds back only the gaussians
    # that draw pixels of the lagging times' training views off by more than this (mean absolute
    # colour error, 0..1), the rest of the scene freezes; 0 holds back every gaussian
    static_hold_error: float = 0.0
    # stop when converged (trase.convergence): every stop_interval iterations (0 = off, the
    # public code's full schedule) the PSNR of the training views held out for it (every
    # stop_holdout_every-th in time order, not trained on) is measured; the run stops once it
    # has not risen by stop_min_delta dB for stop_patience checks in a row, not before
    # stop_floor nor before the warm-up ends, and at `iterations` at the latest
    stop_interval: int = 0
    stop_patience: int = 2
    stop_min_delta: float = 0.05
    stop_floor: int = 0
    stop_holdout_every: int = 10
    # torch intra-op threads while training (the deformation network; the rasterizer runs on
    # numba's own threads)
    torch_threads: int = 1
    # where training runs: "cpu" (numba rasterizer), "cuda" (torch on the GPU, gsplat
    # rasterizer) or "auto" (cuda when torch sees a GPU); the benchmark resolves it before a run
    device: str = "auto"
    time_noise: float = 0.1
    time_noise_steps: int = 20_000
    # data and bookkeeping
    image_downscale: float = 1.0
    seed: int = 0
    checkpoint_interval: int = 5_000  # also saved at the end
    log_interval: int = 10

    @classmethod
    def paper(cls, **overrides) -> ReconstructionConfig:
        """The public TRASE code's settings (its defaults differ from Deformable-3DGS's in
        densify_grad_threshold and scaling_lr). The per-dataset ``warm_up`` / ``densify_until``
        are the benchmark's to add (trase knows no dataset)."""
        return cls(**overrides)

    def __post_init__(self) -> None:
        deform_shape(self.deform_preset)  # a bad name fails here, not after the warm-up
        if not (math.isfinite(self.near_plane) and self.near_plane > 0):
            raise ValueError(f"near_plane must be a positive number of scene units, got {self.near_plane!r}")
        if self.deform_scale_rule not in ("mirror", "clamp"):
            raise ValueError(f"deform_scale_rule must be mirror or clamp, got {self.deform_scale_rule!r}")
        if (self.static_threshold < 0 or self.static_interval < 1 or self.static_from < 0 or self.static_time_gap < 0
                or self.static_hold_error < 0):
            raise ValueError("static_threshold, static_from, static_time_gap and static_hold_error must be >= 0 and "
                             f"static_interval >= 1, got {self.static_threshold}, {self.static_from}, "
                             f"{self.static_time_gap}, {self.static_hold_error} and {self.static_interval}")
        if self.static_hold_error >= 1 or (self.static_hold_error > 0 and self.static_time_gap <= 0):
            raise ValueError("static_hold_error must be below 1 (a colour error no pixel reaches holds nothing) and "
                             f"needs a static_time_gap > 0 (it acts above the gap), got {self.static_hold_error} with "
                             f"static_time_gap {self.static_time_gap}")
        self.stop_rule()  # a bad stopping rule fails here
        if self.stop_interval > 0 and self.stop_holdout_every < 2:
            raise ValueError(f"stop_holdout_every must be >= 2 when stopping is on, got {self.stop_holdout_every}")
        if self.resolution_schedule not in RESOLUTION_SCHEDULES or self.primitive_schedule not in PRIMITIVE_SCHEDULES:
            raise ValueError(f"resolution_schedule must be one of {', '.join(RESOLUTION_SCHEDULES)} and "
                             f"primitive_schedule one of {', '.join(PRIMITIVE_SCHEDULES)}, got "
                             f"{self.resolution_schedule!r} and {self.primitive_schedule!r}")
        if not (self.resolution_max_factor >= 1 and self.resolution_until >= 0):
            raise ValueError(f"resolution_max_factor must be >= 1 and resolution_until >= 0, got "
                             f"{self.resolution_max_factor} and {self.resolution_until}")
        if self.primitive_schedule == "resolution" and self.resolution_schedule == "off":
            raise ValueError("primitive_schedule 'resolution' follows the rendered size: it needs a resolution_schedule "
                             "('frequency' follows the images' spectrum at full size)")
        if self.densify_statistic not in DENSIFY_STATISTICS:
            raise ValueError(f"densify_statistic must be one of {', '.join(DENSIFY_STATISTICS)}, "
                             f"got {self.densify_statistic!r}")

    def stop_rule(self):
        """The stopping rule of the stop_* settings (``trase.convergence.StopRule``)."""
        from trase.convergence import StopRule

        return StopRule(self.stop_interval, self.stop_patience, self.stop_min_delta,
                        max(self.stop_floor, self.warm_up), higher_is_better=True)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def expon_lr(step: int, lr_init: float, lr_final: float, max_steps: int) -> float:
    """Log-linear decay from lr_init to lr_final over max_steps (3DGS's get_expon_lr_func
    with no delay), constant afterwards."""
    if lr_init <= 0 or lr_final <= 0:
        return 0.0
    t = min(max(step / max(max_steps, 1), 0.0), 1.0)
    return math.exp(math.log(lr_init) * (1 - t) + math.log(lr_final) * t)


def time_noise_scale(step: int, cfg: ReconstructionConfig) -> float:
    """Linear anneal of the time-noise amplitude to zero over time_noise_steps."""
    t = min(max(step / max(cfg.time_noise_steps, 1), 0.0), 1.0)
    return cfg.time_noise * (1.0 - t)
