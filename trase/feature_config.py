"""Settings of feature learning: the typed config (its defaults are the public TRASE code's,
the ``paper`` preset) and its presets, declared as data (lazyspecs.presets)."""

from __future__ import annotations

import dataclasses

from lazyspecs.presets import Context, PresetTable

# the cpu preset samples at most this many pixels per step (Np^2 pairs). Kept at 2000 with the
# fused objective: Np 5000 made 1000 steps 3.5x slower (76-94 s) for no consistent gain on the
# synthetic formats (mIoU nerfds 0.893 -> 0.896, hypernerf 0.900 -> 0.881, neu3d 0.874 -> 0.890,
# immersive 0.881 -> 0.829, technicolor 0.904 -> 0.906); more steps at 2000 did better.
CPU_MAX_PIXELS = 2000


@dataclasses.dataclass
class FeatureConfig:
    dim: int = 32
    iterations: int = 10000
    lr: float = 0.0025
    eps: float = 1e-15
    n_pixels: int = 5000  # Np (5000 monocular, 10000 multi-view in the paper)
    n_masks: float = 25  # M' (25 monocular, 50 multi-view)
    mask_rule: str = "random"  # masks.sampling rule
    knn: int = 16  # smoothing neighbours, 0 = no smoothing
    knn_keep: int = 8  # neighbour slots averaged per step
    # the smoothed features L2-normalised again before rendering, as the public trainer renders
    # (``norm_gaussian_features=True``); False renders the neighbour mean as it is (norm <= 1)
    renormalize: bool = True
    # pixels the feature-norm regulariser averages over: "image" = every pixel of the rendered
    # view (the public code: one more full-view render per step), "sampled" = the Np sampled
    # pixels only (cheaper: no full-view render)
    norm_reg_pixels: str = "image"
    objective: str = "trase"
    objective_params: dict = dataclasses.field(default_factory=dict)
    seed: int = 0
    # frozen-geometry fast path: True, False (rasterize every step) or "auto": the fast path
    # when a view is drawn at least FASTPATH_MIN_USES times on average (see there)
    fastpath: bool | str = "auto"
    min_weight: float = 0.0  # fast path: drop contributors below this weight
    max_cache_bytes: int = 1 << 30  # fast path RAM budget
    render_backend: str = "auto"  # rasterizer backend when fastpath=False
    mask_cache: int = 8  # MaskSets kept in RAM
    torch_threads: int = 0  # intra-op threads while training; 0 = leave torch's setting
    # where training runs: "cpu", "cuda" (gsplat rasterizer, torch objective) or "auto" (cuda
    # when torch sees a GPU); the benchmark resolves it before a run. Results come back on the CPU.
    device: str = "auto"
    # stop when converged (trase.convergence): every stop_interval steps (0 = off, the public
    # code's full schedule) the objective's loss on fixed samples of the training views held out
    # for it (every stop_holdout_every-th in time order, not trained on), with the features as
    # they are saved (smoothed over all K neighbours); the stage stops once that loss has not
    # fallen by stop_min_delta x |its first check| for stop_patience checks in a row, not before
    # stop_floor steps, and at `iterations` at the latest
    stop_interval: int = 0
    stop_patience: int = 2
    stop_min_delta: float = 0.01
    stop_floor: int = 0
    stop_holdout_every: int = 10

    def stop_rule(self):
        """The stopping rule of the stop_* settings (``trase.convergence.StopRule``)."""
        from trase.convergence import StopRule

        return StopRule(self.stop_interval, self.stop_patience, self.stop_min_delta, self.stop_floor,
                        higher_is_better=False, relative=True)

    @classmethod
    def preset(cls, name: str, **overrides) -> FeatureConfig:
        """Preset ``name`` of FEATURE_PRESETS (``paper``: the public code's settings; ``cpu``:
        fewer, larger steps for 2-core CPUs) with ``overrides``."""
        return dataclasses.replace(FEATURE_PRESETS.resolve(name, Context()).config, **overrides)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class FeaturePresetError(LookupError):
    user_facing = True


FEATURE_PRESETS = PresetTable("feature", FeatureConfig, error=FeaturePresetError)
FEATURE_PRESETS.declare("paper", help="the public TRASE code's settings (10k steps at lr 0.0025)")
# cpu: fewer, larger steps for 2-core CPUs.
# One torch thread: on a small shared CPU, OpenMP barriers between two busy cores made every
# step ~10x slower than a single thread (measured).
# Fewer, larger steps: with lr 0.0025 features barely turn in a few thousand steps (measured on
# the synthetic nerfds scene: mIoU 0.11 after 1500 steps at 0.0025, 0.62 after 3000 steps at
# 0.05 with a 500-point clustering sample; 0.83 after 800 steps once the sample floor is 5000).
# 3000 steps since the fused objective made a step ~22 ms at Np 2000 (synthetic scenes,
# ground-truth geometry, 2 shared cores): the objects' gaussians' similarity to their cluster
# mean rises (5th percentile 0.69-0.89 -> 0.80-0.93 over the five formats), which the cpu
# filter threshold relies on; features ~66 s quiet, 89-106 s under load (1000 steps: 20-30 s).
# Np is capped by the method (CPU_MAX_PIXELS).
# The norm regulariser over the sampled pixels, not the whole view: the full-view render made a
# step 1.23x slower (50 -> 62 ms, synthetic HyperNeRF scene of seed 1, ground-truth geometry,
# 600 steps, one thread beside another job) for the same mIoU there (0.9257 sampled, 0.9256 image).
# lr 0.1: chosen with the clustering constants on synthetic scenes of another seed than the
# benchmark's (benchmark.methods.trase_presets); 0.025-0.1 scored within 0.001 of each other there.
FEATURE_PRESETS.declare("cpu", base="paper", help="3000 steps at lr 0.1 on one thread, the norm regulariser on the sampled pixels",
                        iterations=3000, lr=0.1, torch_threads=1, norm_reg_pixels="sampled")


__all__ = ["CPU_MAX_PIXELS", "FEATURE_PRESETS", "FeatureConfig", "FeaturePresetError"]
