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
from pathlib import Path

import numpy as np

from benchmark.methods import FittedModel, MethodError, register_method
from benchmark.methods.trase_method import TraseMethod, click_view

BASELINE_METHODS = ("trase-hard", "trase-all", "cgc", "opengaussian")


@register_method("trase-hard")
class TraseHardMethod(TraseMethod):
    """TRASE pipeline, hard-mining objective (only individually violating pairs)."""

    objective = "trase-hard"


@register_method("trase-all")
class TraseAllMethod(TraseMethod):
    """TRASE pipeline, all-mining objective (every pixel with a pair is an anchor)."""

    objective = "trase-all"


@register_method("cgc")
class CGCMethod(TraseMethod):
    """Contrastive Gaussian Clustering: CGC objective and CGC's similarity-threshold selection."""

    objective = "cgc"

    def default_config(self, dataset: str | None, preset: str, monocular: bool = True) -> dict:
        from baselines.cgc_inference import PATCH, THRESHOLD

        cfg = super().default_config(dataset, preset, monocular)
        params = cfg["features"]["objective_params"]
        # "auto": the public 100-pixel threshold rescaled to the mask resolution (see baselines/cgc.py)
        params.setdefault("min_mask_pixels", "auto")
        cfg["cgc"] = {"threshold": THRESHOLD, "patch": PATCH}
        cfg["filter_threshold"] = None  # CGC's own threshold replaces TRASE's filter
        return cfg

    def learn(self, scene, gaussians, deformation, masks_dir: Path, config: dict, work_dir: Path,
              progress: bool = True):
        cfg = copy.deepcopy(config)
        params = cfg["features"].setdefault("objective_params", {})
        if params.get("min_mask_pixels", "auto") == "auto":
            params["min_mask_pixels"] = _auto_min_mask_pixels(scene, masks_dir)
        feats, info = super().learn(scene, gaussians, deformation, masks_dir, cfg, work_dir, progress)
        info["min_mask_pixels"] = params["min_mask_pixels"]
        return feats, info

    def group(self, feats, config: dict, gaussians=None, deformation=None, learn_info=None) -> FittedModel:
        shared = copy.deepcopy(config)
        shared["filter_threshold"] = -1.0  # the shared grouping needs a number; keep is replaced
        fitted = super().group(feats, shared, gaussians, deformation, learn_info)
        fitted.config = copy.deepcopy(config)
        resolved = (learn_info or {}).get("min_mask_pixels")
        if resolved is not None:  # record the threshold "auto" resolved to
            fitted.config["features"].setdefault("objective_params", {})["min_mask_pixels"] = resolved
        fitted.keep = np.ones(fitted.labels.shape, bool)  # CGC's own threshold replaces the filter
        fitted.stats["kept_fraction"] = 1.0
        fitted.stats["min_mask_pixels"] = resolved
        return fitted

    selects_clusters = False  # clicks query features in a patch, not clusters

    def segment(self, fitted: FittedModel, scene, prompts) -> list[np.ndarray]:
        import torch

        from baselines.cgc_inference import PATCH, THRESHOLD, select_by_clicks
        from trase.segment import render_masks

        if fitted.gaussians is None:
            raise MethodError(
                "segment needs the fitted model's geometry (FittedModel.gaussians is None)"
            )
        ccfg = fitted.config.get("cgc", {})
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
                float(ccfg.get("threshold", THRESHOLD)),
                int(ccfg.get("patch", PATCH)),
            )
        fitted.stats["selected_gaussians"] = int(sel.sum())
        thr = float(fitted.config.get("alpha_threshold", 0.5))
        rule = str(fitted.config.get("render_rule", "alone"))  # as its oracle and the ceiling
        return render_masks(
            fitted.gaussians, fitted.deformation, sel, [v.camera for v in scene.test], thr, rule
        )


@register_method("opengaussian")
class OpenGaussianMethod(TraseMethod):
    """OpenGaussian's stage-1 objective; shared clustering in place of its codebook, no filter."""

    objective = "opengaussian"

    def default_config(self, dataset: str | None, preset: str, monocular: bool = True) -> dict:
        cfg = super().default_config(dataset, preset, monocular)
        cfg["filter_threshold"] = None  # every gaussian keeps its class (codebook semantics)
        return cfg

    def group(self, feats, config: dict, gaussians=None, deformation=None, learn_info=None) -> FittedModel:
        shared = copy.deepcopy(config)
        if shared.get("filter_threshold") is None:
            shared["filter_threshold"] = -1.0
        fitted = super().group(feats, shared, gaussians, deformation, learn_info)
        fitted.config = copy.deepcopy(config)
        if config.get("filter_threshold") is None:
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
    "CGCMethod",
    "OpenGaussianMethod",
    "TraseAllMethod",
    "TraseHardMethod",
]
