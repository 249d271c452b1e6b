"""Baseline methods: the TRASE pipeline with another feature objective (``baselines/``).

Every method here shares the frozen geometry, masks, mask/pixel sampling, smoothing, the fast
path and the click prompts with ``trase``; only what the baseline's paper changes differs:

``trase-hard``    objective ``trase-hard`` (hard mining ablation); rest as TRASE, including
                  HDBSCAN clustering and the similarity filter.
``trase-all``     objective ``trase-all`` (all mining ablation); rest as TRASE.
``cgc``           objective ``cgc`` (2D label-map contrast + 3D spatial term). Inference is
                  CGC's own, not clustering: a click's 5x5 rendered-feature patch is the query
                  and every gaussian with cosine >= 0.7 to it is selected (union over clicks);
                  no TRASE filter (CGC's threshold is its filter, as the paper notes). The
                  shared clustering still runs, only for the feature-space statistics
                  (intra/inter distances) and the oracle bound.
``opengaussian``  objective ``opengaussian`` (stage-1 intra/inter-mask loss). OpenGaussian
                  assigns gaussians to classes with a two-level k-means codebook (its stage 2,
                  retraining against pseudo-labels); that stage is NOT implemented: the shared
                  HDBSCAN clustering and click selection stand in for it, and no similarity
                  filter is applied (the codebook assigns every gaussian, the paper notes the
                  filter does not apply). Needs the rendered alpha of the sampled pixels in
                  each ``PixelSample`` (see ``OpenGaussianObjective``).
"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path

import numpy as np

from baselines.cgc_inference import PATCH, THRESHOLD
from benchmark.methods import FittedModel, MethodError, register_method
from benchmark.methods.trase_method import TraseMethod, click_view
from benchmark.methods.trase_presets import TRASE_PRESETS, TraseSettings
from lazyspecs.presets import MONOCULAR

BASELINE_METHODS = ("trase-hard", "trase-all", "cgc", "opengaussian")


# trase-hard's own cpu choices: its features (hard mining) cluster otherwise than TRASE's, and
# with TRASE's clustering (min_cluster_size 50 over every gaussian) its click on the benchmark's
# HyperNeRF-format scene chose a background-sized cluster (mIoU 0.13, oracle 0.64). Chosen the way
# TRASE's were (docs/notes/cpu-constants.md, "The ablation methods' own settings"): on the
# seed-1 scenes of the five formats, ground-truth geometry, by the mean official mIoU over a grid of
# min_cluster_size {25, 50, 100} x filter {0.6, 0.7, 0.8} (and the click rule "weight" at filter
# 0.7, which chose as "feature" did): 25 and 0.6, mean 0.388 (0.8: 0.388 too, 0.3879 against
# 0.3882; TRASE's 50 and 0.7: 0.186). The features' learning rate was not searched again.
TRASE_HARD_PRESETS = TRASE_PRESETS.extended("trase-hard")
TRASE_HARD_PRESETS.declare("cpu", {"clustering.params.min_cluster_size": 25}, filter_threshold=0.6)
# the other objectives train the whole feature schedule: TRASE's stopping rule (trase_presets)
# was chosen on TRASE's loss, not theirs
FULL_FEATURE_SCHEDULE = {"features.stop_interval": 0}
TRASE_HARD_PRESETS.declare("cpu", FULL_FEATURE_SCHEDULE)
TRASE_ALL_PRESETS = TRASE_PRESETS.extended("trase-all")
TRASE_ALL_PRESETS.declare("cpu", FULL_FEATURE_SCHEDULE)


@register_method("trase-hard")
class TraseHardMethod(TraseMethod):
    """TRASE pipeline, hard-mining objective (only individually violating pairs)."""

    objective = "trase-hard"
    presets = TRASE_HARD_PRESETS


@register_method("trase-all")
class TraseAllMethod(TraseMethod):
    """TRASE pipeline, all-mining objective (every pixel with a pair is an anchor)."""

    objective = "trase-all"
    presets = TRASE_ALL_PRESETS


@dataclasses.dataclass
class CGCInference:
    """CGC's selection: a click's PATCHxPATCH rendered-feature patch is the query, every
    gaussian with cosine >= threshold to it is selected (baselines.cgc_inference)."""

    threshold: float = THRESHOLD
    patch: int = PATCH


@dataclasses.dataclass
class CGCSettings(TraseSettings):
    cgc: CGCInference = dataclasses.field(default_factory=CGCInference)


CGC_PRESETS = TRASE_PRESETS.extended("cgc", CGCSettings)
# CGC's own threshold replaces TRASE's filter; "auto": the public 100-pixel small-segment
# threshold rescaled to the mask resolution (baselines/cgc.py)
CGC_PRESETS.declare("paper", {"features.objective_params": {"min_mask_pixels": "auto"}}, filter_threshold=None)
CGC_PRESETS.declare("cpu", FULL_FEATURE_SCHEDULE, filter_threshold=None)
# cgc's own cpu threshold, per rig: chosen on the seed-1 selection scenes with reconstructed
# geometry (the main protocol's), by the mean official mIoU of each rig's formats over {0.6, 0.7,
# 0.8, 0.9}, a value replacing the public code's 0.7 only when better by more than 0.005
# (docs/notes/cpu-constants.md): the monocular ones (NeRF-DS, HyperNeRF) 0.6; the multi-view
# ones keep 0.7 (mean 0.935; 0.9: 0.879). A first grid on ground-truth geometry had chosen 0.9 for
# the multi-view rigs, where CGC's features are sharper than on the geometry the benchmark scores
CGC_PRESETS.declare("cpu", {"cgc.threshold": 0.6}, when=MONOCULAR)

OPENGAUSSIAN_PRESETS = TRASE_PRESETS.extended("opengaussian")
# every gaussian keeps its class (codebook semantics): no filter
OPENGAUSSIAN_PRESETS.declare("paper", filter_threshold=None)
OPENGAUSSIAN_PRESETS.declare("cpu", FULL_FEATURE_SCHEDULE, filter_threshold=None)


@register_method("cgc")
class CGCMethod(TraseMethod):
    """Contrastive Gaussian Clustering: CGC objective and CGC's similarity-threshold selection."""

    objective = "cgc"
    presets = CGC_PRESETS

    def learn(self, scene, gaussians, deformation, masks_dir: Path, config: CGCSettings, work_dir: Path,
              progress: bool = True):
        cfg = copy.deepcopy(config)
        params = cfg.features.objective_params
        if params.get("min_mask_pixels", "auto") == "auto":
            params["min_mask_pixels"] = _auto_min_mask_pixels(scene, masks_dir)
        feats, info = super().learn(scene, gaussians, deformation, masks_dir, cfg, work_dir, progress)
        info["min_mask_pixels"] = params["min_mask_pixels"]
        return feats, info

    def group(self, feats, config: CGCSettings, gaussians=None, deformation=None, learn_info=None) -> FittedModel:
        # the shared grouping needs a number; keep is replaced
        fitted = super().group(feats, dataclasses.replace(config, filter_threshold=-1.0), gaussians, deformation,
                               learn_info)
        fitted.config = copy.deepcopy(config)
        resolved = (learn_info or {}).get("min_mask_pixels")
        if resolved is not None:  # record the threshold "auto" resolved to
            fitted.config.features.objective_params["min_mask_pixels"] = resolved
        fitted.keep = np.ones(fitted.labels.shape, bool)  # CGC's own threshold replaces the filter
        fitted.stats["kept_fraction"] = 1.0
        fitted.stats["min_mask_pixels"] = resolved
        return fitted

    selects_clusters = False  # clicks query features in a patch, not clusters
    negative_clicks = False  # CGC's selection is a union of similarity queries: positive clicks only

    def segment(self, fitted: FittedModel, scene, prompts) -> list[np.ndarray]:
        import torch

        from baselines.cgc_inference import select_by_clicks
        from trase.segment import render_masks

        if fitted.gaussians is None:
            raise MethodError(
                "segment needs the fitted model's geometry (FittedModel.gaussians is None)"
            )
        ccfg = fitted.config.cgc
        by_view: dict[str, tuple] = {}  # clicks grouped by the frame they were made in
        for c in prompts.clicks:
            view = click_view(scene, prompts, c)
            by_view.setdefault(view.name, (view, []))[1].append(c)
        sel = np.zeros(fitted.features.shape[0], bool)
        for view, clicks in by_view.values():  # the union over clicks, as CGC's selection is
            sel |= select_by_clicks(
                fitted.gaussians,
                fitted.deformation,
                torch.from_numpy(fitted.features),
                view.camera,
                clicks,
                float(ccfg.threshold),
                int(ccfg.patch),
            )
        fitted.stats["selected_gaussians"] = int(sel.sum())
        # as its oracle and the ceiling
        thr, rule = float(fitted.config.alpha_threshold), str(fitted.config.render_rule)
        return render_masks(
            fitted.gaussians, fitted.deformation, sel, [v.camera for v in scene.test], thr, rule
        )


@register_method("opengaussian")
class OpenGaussianMethod(TraseMethod):
    """OpenGaussian's stage-1 objective; shared clustering in place of its codebook, no filter."""

    objective = "opengaussian"
    presets = OPENGAUSSIAN_PRESETS

    def group(self, feats, config: TraseSettings, gaussians=None, deformation=None, learn_info=None) -> FittedModel:
        shared = config if config.filter_threshold is not None else dataclasses.replace(config, filter_threshold=-1.0)
        fitted = super().group(feats, shared, gaussians, deformation, learn_info)
        fitted.config = copy.deepcopy(config)
        if config.filter_threshold is None:
            fitted.keep = np.ones(fitted.labels.shape, bool)
            fitted.stats["kept_fraction"] = 1.0
        return fitted


def _auto_min_mask_pixels(scene, masks_dir: Path) -> int:
    """CGC's 100-pixel small-segment threshold at the resolution of this scene's masks."""
    import masks as masklib
    from baselines.cgc import min_mask_pixels_for

    for view in scene.train:
        p = masklib.mask_path(Path(masks_dir), view.name)
        if p.is_file():
            ms = masklib.load(p)
            return min_mask_pixels_for(ms.height, ms.width)
    raise MethodError(f"{masks_dir}: no masks for any training view of {scene.root}")


__all__ = [
    "BASELINE_METHODS",
    "CGCInference",
    "CGCMethod",
    "CGCSettings",
    "OpenGaussianMethod",
    "TraseAllMethod",
    "TraseHardMethod",
]
