"""The ``trase`` benchmark method: feature learning on frozen geometry with an objective
(TRASE's soft mining by default), clustering, similarity filter, click prompts, rendering.

Baselines reuse this class with another objective: ``TraseMethod(objective="trase-hard")``
or a subclass registered under another name with ``objective = "..."``.
"""

from __future__ import annotations

import dataclasses
import inspect
import time
from pathlib import Path

import numpy as np

import baselines  # noqa: F401 (registers the baseline objectives: TraseMethod(objective=...) takes any)
from benchmark.methods import FittedModel, Method, MethodError, click_view, register_method
from benchmark.methods.trase_presets import TRASE_PRESETS, TraseSettings
from lazyspecs.presets import Context, Resolved


@register_method("trase")
class TraseMethod(Method):
    objective: str = "trase"

    def __init__(self, objective: str | None = None, objective_params: dict | None = None) -> None:
        if objective is not None:
            self.objective = objective
        self.objective_params = dict(objective_params or {})

    # -- settings --------------------------------------------------------------------
    presets = TRASE_PRESETS  # benchmark.methods.trase_presets: paper and cpu, per benchmark and rig

    def resolve_settings(self, preset: str, ctx: Context) -> Resolved:
        """The declared settings with this method's objective (``objective``, or the one given
        to the constructor) and its parameters on top of the declared ones. Declarations that
        depend on the objective read the run's (``ctx.objective``: --set's), else this one."""
        if ctx.objective is None:
            ctx = dataclasses.replace(ctx, objective=self.objective)
        r = super().resolve_settings(preset, ctx)
        features = r.config.features
        features.objective = self.objective
        features.objective_params = {**features.objective_params, **self.objective_params}
        where = f"the method's objective ({type(self).__name__})"
        return dataclasses.replace(r, sources={**r.sources, "features.objective": where,
                                               **({"features.objective_params": where} if self.objective_params else {})})

    def check_settings(self, settings: TraseSettings) -> None:
        from benchmark.config import ConfigError
        from benchmark.methods import check_clustering
        from trase.prompts import ON_SELECTED

        check_clustering(settings.clustering)
        if not float(settings.unseen_min_weight) >= 0:
            raise ConfigError(f"--set method.unseen_min_weight={settings.unseen_min_weight!r}: a weight >= 0 (0: off)")
        if isinstance(settings.unseen_neighbours, bool) or int(settings.unseen_neighbours) < 1:
            raise ConfigError(f"--set method.unseen_neighbours={settings.unseen_neighbours!r}: a whole number >= 1")
        _check_objective_params(settings.features.objective, settings.features.objective_params)
        if settings.prompts.on_selected not in ON_SELECTED:
            raise ConfigError(f"--set method.prompts.on_selected={settings.prompts.on_selected!r}: one of "
                              f"{', '.join(ON_SELECTED)}")

    # -- fit = learn (features: the slow part) then group (clustering + filter) ----------
    FEATURE_FIELDS = ("features",)  # the settings that change the learned features

    def learn(self, scene, gaussians, deformation, masks_dir: Path, config: TraseSettings, work_dir: Path,
              progress: bool = True) -> tuple[np.ndarray, dict]:
        """Train per-gaussian features [N, D] on frozen geometry -> (features, info)."""
        import masks as masklib
        from benchmark.methods import checkpoint_seconds
        from trase.devices import peak_memory_mib, reset_peak_memory, resolve_device
        from trase.features import train_features

        work_dir = Path(work_dir)
        masks_dir = Path(masks_dir)
        fcfg = config.features

        def load_masks(view):
            p = masklib.mask_path(masks_dir, view.name)
            if not p.is_file():
                raise MethodError(f"{p}: masks of training view {view.name} not found")
            return masklib.load(p)

        device = resolve_device(fcfg.device)
        reset_peak_memory(device)
        res = train_features(gaussians, deformation, scene.train, load_masks, fcfg,
                             cache_dir=work_dir / "pixel_weights", progress=progress,
                             checkpoint=work_dir / "features_checkpoint.pt", checkpoint_every_s=checkpoint_seconds())
        peak = peak_memory_mib(device)
        feats = res.features.detach().cpu().numpy().astype(np.float32)
        info = {
            "timings": {"features_prepare": res.timings["prepare"], "features_train": res.timings["train"],
                        "features_per_step": res.timings["per_step"]},
            "resumed_from_step": res.timings["resumed_from_step"],  # > 0: a killed or requeued job went on
            "path": res.path_stats,
            "loss_tail": res.history[-5:],
            "objective": fcfg.objective,
            **({"stopping": res.stopping} if res.stopping is not None else {}),
            **({"peak_gpu_mib": peak} if peak is not None else {}),
        }
        return feats, info

    def group_inputs(self, scene, gaussians, deformation, config: TraseSettings) -> dict:
        """The training images' compositing weight per gaussian, where unseen gaussians take
        their neighbours' features (``unseen_min_weight`` > 0)."""
        if float(config.unseen_min_weight) <= 0 or gaussians is None:
            return {}
        from trase.unseen import training_weights

        return {"training_weights": training_weights(gaussians, deformation, [v.camera for v in scene.train])}

    def group(self, feats: np.ndarray, config: TraseSettings, gaussians=None, deformation=None,
              learn_info: dict | None = None) -> FittedModel:
        """Cluster features, assign every gaussian, filter by similarity -> FittedModel."""
        from trase.clustering import cluster, filter_by_similarity
        from trase.feature_stats import feature_space_stats

        learn_info = dict(learn_info or {})
        feats, unseen = _unseen_from_neighbours(feats, config, gaussians, learn_info.pop("training_weights", None))
        ccfg = config.clustering
        t0 = time.perf_counter()
        cl = cluster(feats, method=ccfg.method, fraction=float(ccfg.fraction), seed=int(ccfg.seed),
                     min_sample=int(ccfg.min_sample), **ccfg.params)
        t_cluster = time.perf_counter() - t0
        keep = filter_by_similarity(feats, cl.labels, float(config.filter_threshold))
        fs = feature_space_stats(feats, cl.labels)
        stats = {
            "n_gaussians": int(feats.shape[0]),
            "n_clusters": cl.n_clusters,
            "cluster_sample": int(cl.sample.size),  # gaussians the clustering itself saw
            "kept_fraction": float(keep.mean()) if keep.size else 0.0,
            "feature_space": fs.to_dict(),
            "path": learn_info.get("path", {}),
            "loss_tail": learn_info.get("loss_tail", []),
            "objective": learn_info.get("objective"),
            **({"unseen_gaussians": unseen} if unseen is not None else {}),
            **({"peak_gpu_mib": learn_info["peak_gpu_mib"]} if "peak_gpu_mib" in learn_info else {}),
        }
        timings = {**learn_info.get("timings", {}), "clustering": t_cluster}
        return FittedModel(feats, cl.labels, keep, timings, stats, config, gaussians, deformation)

    # -- segment -----------------------------------------------------------------------
    # segment = select clusters by clicks, then render_selection (evaluate re-renders a click
    # set that chose the same clusters from memory)
    selects_clusters = True
    negative_clicks = True  # a negative click removes its cluster and keeps it out (trase.prompts)

    def click_selection(self, fitted: FittedModel, scene, prompts) -> tuple[list[int], list[int]]:
        """(the clusters the prompt clicks select, the cluster of each click in click order; -1:
        a click on no surface): positive clicks add, negative ones remove and keep out
        (trase.prompts.clicks_to_clusters)."""
        from trase.prompts import clicks_to_clusters

        clicks = fitted.config.prompts
        cameras = [click_view(scene, prompts, c).camera for c in prompts.clicks]
        return clicks_to_clusters(fitted.gaussians, fitted.deformation, cameras, list(prompts.clicks), fitted.labels,
                                  min_alpha=float(clicks.min_alpha), rule=str(clicks.click_rule),
                                  radius=int(clicks.click_radius), features=fitted.features,
                                  front_share=float(clicks.front_share), on_selected=str(clicks.on_selected))

    def click_clusters(self, fitted: FittedModel, scene, prompts) -> list[int]:
        """The cluster each prompt click chose, in click order (-1: a click on no surface)."""
        return self.click_selection(fitted, scene, prompts)[1]

    def select(self, fitted: FittedModel, scene, prompts) -> list[int]:
        """Prompt clicks -> chosen cluster ids (clicks on no surface choose nothing)."""
        return self.click_selection(fitted, scene, prompts)[0]

    def segment(self, fitted: FittedModel, scene, prompts) -> list[np.ndarray]:
        """Masks of the test views for the clusters the clicks choose; records the cluster of
        each click (``stats["click_clusters"]``) and the chosen set (``selected_clusters``)."""
        clusters, per_click = self.click_selection(fitted, scene, prompts) if fitted.gaussians is not None else ([], [])
        fitted.stats["click_clusters"] = per_click
        fitted.stats["selected_clusters"] = clusters
        return self.render_selection(fitted, scene, clusters)

    def render_selection(self, fitted: FittedModel, scene, clusters: list[int]) -> list[np.ndarray]:
        """Masks [H, W] bool of the test views for the chosen clusters (the method's filter and
        rendering rule)."""
        from trase.segment import render_masks, select_gaussians

        if fitted.gaussians is None:
            raise MethodError("segment needs the fitted model's geometry (FittedModel.gaussians is None)")
        sel = select_gaussians(fitted.labels, clusters, fitted.keep)
        thr, rule = float(fitted.config.alpha_threshold), str(fitted.config.render_rule)
        return render_masks(fitted.gaussians, fitted.deformation, sel, [v.camera for v in scene.test], thr, rule)

    def segment_oracle(self, fitted: FittedModel, scene, gts: list[np.ndarray]) -> tuple[list[np.ndarray], list[int]]:
        """Upper bound: clusters mostly inside the ground truth (all test frames), rendered
        with the same filter. Report separately; never the method's score."""
        from benchmark.protocol.oracle import oracle_clusters
        from trase.segment import render_masks, select_gaussians

        cams = [v.camera for v in scene.test]
        clusters = oracle_clusters(fitted.gaussians, fitted.deformation, cams, gts, fitted.labels)
        sel = select_gaussians(fitted.labels, clusters, fitted.keep)
        thr, rule = float(fitted.config.alpha_threshold), str(fitted.config.render_rule)
        return render_masks(fitted.gaussians, fitted.deformation, sel, cams, thr, rule), clusters


def _unseen_from_neighbours(feats: np.ndarray, config: TraseSettings, gaussians, weights) -> tuple[np.ndarray, int | None]:
    """(features, how many gaussians took their neighbours' features; None when off)."""
    if weights is None:
        return feats, None
    from trase.unseen import neighbours_features

    seen = np.asarray(weights) >= float(config.unseen_min_weight)
    means = gaussians.means.detach().cpu().numpy()
    return neighbours_features(feats, means, seen, int(config.unseen_neighbours)), int((~seen).sum())


def _check_objective_params(name: str, params: dict) -> None:
    """A parameter the objective's class does not take stops the run before any stage."""
    from benchmark.config import ConfigError
    from trase.objectives.base import OBJECTIVES

    taken = inspect.signature(OBJECTIVES.load(name)).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in taken.values()):
        return
    for key in params:
        if key not in taken:
            raise ConfigError(f"--set method.features.objective_params.{key}: objective {name!r} takes no such "
                              f"parameter (it takes {', '.join(taken) or 'none'})")


def with_objective(objective: str, **params) -> TraseMethod:
    """A TRASE pipeline with another objective (for ablations and baselines)."""
    return TraseMethod(objective=objective, objective_params=params)


__all__ = ["TraseMethod", "with_objective"]
