"""The ``trase`` benchmark method: feature learning on frozen geometry with an objective
(TRASE's soft mining by default), clustering, similarity filter, click prompts, rendering.

Baselines reuse this class with another objective: ``TraseMethod(objective="trase-hard")``
or a subclass registered under another name with ``objective = "..."``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import baselines  # noqa: F401 (registers the baseline objectives: TraseMethod(objective=...) takes any)
from benchmark.methods import FittedModel, Method, MethodError, register_method
from benchmark.methods.trase_settings import dataset_settings
from trase.reconstruction_config import CPU_CHANGES

# The cpu preset's constants: similarity filter, HDBSCAN min_cluster_size, and (in
# trase.features) the feature learning rate. Chosen on scenes the benchmark never reports: the
# synthetic scenes of seed 1 of all five formats (`trase-bench synth --seed 1`), ground-truth
# geometry, the argmax of the mean mIoU over the five over a grid of lr {0.025, 0.05, 0.1} x
# filter {0.6, 0.7, 0.8, 0.9} x min_cluster_size {10, 25, 50} (docs/cpu-constants.md). Taken:
# lr 0.1, filter 0.7, min_cluster_size 25, mean 0.9437; the previous constants (lr 0.05,
# filter 0.8, 25, which had been set on the seed-0 scenes' test views) rank 6th at 0.9427.
# The top eight settings lie within 0.0012: min_cluster_size is the setting that matters
# (50 lost the Immersive ball to a larger cluster, 0.06-0.89; 10 split objects, up to -0.01).
CPU_FILTER_THRESHOLD = 0.7  # similarity filter of the cpu preset, one value for every dataset


def _filter_threshold(paper: float, preset: str) -> float:
    """The paper's per-dataset similarity threshold; CPU_FILTER_THRESHOLD under the cpu preset.

    Why one value: the paper's thresholds (0.4 NeRF-DS ... 0.98 Neu3D) were picked on its own
    features (10k steps at Np 5000-10000). The cpu preset's features (3000 steps at Np <= 2000)
    put the objects' gaussians at 0.80-0.93 similarity to their cluster mean (5th percentile)
    and the other gaussians swept into the same clusters at 0.28 (median), 0.41-0.45 (90th
    percentile): 0.4 keeps floor/wall gaussians, 0.98 prunes the objects (the earlier 0.98 on
    1000-step features kept none of the Neu3D ring: mIoU 0.58). The value itself: see above.
    """
    return CPU_FILTER_THRESHOLD if preset == "cpu" else paper


# HDBSCAN min_cluster_size of the cpu preset (the public code's 10 under 'paper'), and its
# sample: every gaussian of a cpu-preset geometry (at most 15000), not 2% with a 5000 floor.
# Why: with a 5000-point sample, min_cluster_size 25 asks an object for ~75 gaussians; a small
# one falls below it, joins a larger cluster, and the similarity filter then drops it (the
# built-in HyperNeRF scene written as a COLMAP capture: its ball, 72 gaussians, 58 of them in
# a 627-gaussian cluster; IoU of its click 0.001, 0.909 clustering all of them). On the seed-1
# scenes (docs/cpu-constants.md, "Clustering every gaussian") 25 on a 5000 sample (the grid's
# choice above) and 50 on all gaussians tie (mean 0.9214 against 0.9213 over the five
# reconstructed and the two monocular ground-truth geometries, every scene within 0.001); 25
# on all gaussians split an object on the NeRF-DS ground truth (0.973 -> 0.960). Cost: 2 s ->
# 6 s at 15k gaussians.
CPU_MIN_CLUSTER_SIZE = 50
PAPER_MIN_CLUSTER_SIZE = 10  # the public code's HDBSCAN min_cluster_size
CPU_CLUSTER_SAMPLE = CPU_CHANGES["max_gaussians"]  # 15000: every gaussian the cpu preset keeps

# The benchmark's click rule under every preset (trase.prompts.CLICK_RULES). "feature" asks
# which cluster the feature rendered under the click belongs to, the query of feature-field
# click prompts (as DGD's and SAGA's), matched to TRASE's clusters instead of thresholded.
# Chosen on selection scenes (seed 1-3, never the benchmark's seed 0; docs/cpu-constants.md,
# "The click rule"): where "weight" chose a wall behind a semi-transparent ring (0.116, oracle
# 0.898) "feature" reached the oracle; every other scene chose the same clusters by both.
CLICK_RULE = "feature"


def render_rule(preset: str, monocular: bool) -> str:
    """How the selection becomes a 2D mask (trase.segment.RULES): the paper's ``alone``, except
    ``visible`` under the cpu preset on a monocular rig.

    Why: reconstructed from one moving camera on CPU, the objects' gaussians reach beyond their
    outlines where the background hides them (depth along the rays is weakly constrained);
    rendered alone, the halo becomes prediction. Seed-1 scenes (never reported), cpu geometry,
    truth-labelled gaussians, test views: false positives of 14% (HyperNeRF format) and 40%
    (NeRF-DS) of the objects' pixels under ``alone``, 4% and 16% under ``visible``; the
    method's mIoU 0.687 -> 0.792 (NeRF-DS format), 0.841 -> 0.890 (HyperNeRF). On multi-view
    rigs ``visible`` did not help (Neu3D 0.907 -> 0.908, Immersive 0.950 -> 0.938,
    Technicolor 0.970 -> 0.964), so they keep the paper's rule (docs/cpu-constants.md, "The
    render rule")."""
    return "visible" if preset == "cpu" and monocular else "alone"


@register_method("trase")
class TraseMethod(Method):
    objective: str = "trase"

    def __init__(self, objective: str | None = None, objective_params: dict | None = None) -> None:
        if objective is not None:
            self.objective = objective
        self.objective_params = dict(objective_params or {})

    # -- config ------------------------------------------------------------------------
    def default_config(self, dataset: str | None, preset: str, monocular: bool = True) -> dict:
        """Settings for benchmark ``dataset`` (None: a capture of one's own, by its rig) under
        ``preset`` (paper or cpu, resolved once by the benchmark's run config)."""
        from trase.features import CPU_MAX_PIXELS, FeatureConfig

        if preset not in ("paper", "cpu"):
            raise MethodError(f"method preset {preset!r}: choose paper or cpu")
        settings = dataset_settings(dataset, monocular)
        n_pixels = settings.n_pixels
        if preset == "cpu":
            n_pixels = min(n_pixels, CPU_MAX_PIXELS)
        fc = FeatureConfig.preset(
            preset,
            n_pixels=n_pixels,
            n_masks=float(settings.n_masks),
            objective=self.objective,
            objective_params=dict(self.objective_params),
        )
        return {
            "features": fc.to_dict(),
            "preset": preset,
            # HDBSCAN on 2% of the gaussians (public code), but never fewer than 5000: on small
            # scenes 2% is a few hundred points and small objects vanish into noise (synthetic
            # NeRF-DS: mIoU 0.685 with a 500 floor, 0.828 with 5000, same features); at 1M
            # gaussians a 5000-point sample keeps 25%-level agreement (trase-bench perf cluster).
            # The cpu preset clusters every gaussian (CPU_CLUSTER_SAMPLE, see above).
            "clustering": {"method": "hdbscan", "fraction": 0.02,
                           "min_sample": CPU_CLUSTER_SAMPLE if preset == "cpu" else 5000, "seed": 0,
                           "params": {"min_cluster_size": CPU_MIN_CLUSTER_SIZE if preset == "cpu" else PAPER_MIN_CLUSTER_SIZE,
                                      "cluster_selection_epsilon": 0.01}},
            "filter_threshold": _filter_threshold(settings.filter_threshold, preset),
            # click rule: "feature" = the cluster whose mean feature is nearest the feature
            # rendered under the cursor (3x3 window); "weight" = the cluster rendered most there;
            # "depth" = the paper's depth -> 3D -> nearest gaussian (trase.prompts.click_to_cluster).
            # The benchmark's automatic clicks stand in for the paper's manual ones, which a
            # person corrects on sight; on semi-transparent CPU geometry "depth" chose the
            # background for an object click (synthetic NeRF-DS / Immersive: mIoU 0.10 with
            # oracles 0.56 / 0.77), and "weight" did where an object's gaussians stay
            # semi-transparent (a spinning ring: seed-2 HyperNeRF scene, 8x64 network, 0.116
            # with oracle 0.898; "feature" 0.898). CLICK_RULE (above) says how it was chosen.
            "prompts": {"min_alpha": 0.5, "click_rule": CLICK_RULE, "click_radius": 1},
            "alpha_threshold": 0.5,
            # "alone": the paper's rule (selected gaussians rendered without the rest);
            # "visible": their weight in the full render (occluded parts excluded), see trase.segment
            "render_rule": render_rule(preset, monocular),
        }

    def check_config(self, config: dict) -> None:
        from benchmark.config import typed
        from trase.features import FeatureConfig

        typed(FeatureConfig, config["features"], "method.features")

    # -- fit = learn (features: the slow part) then group (clustering + filter) ----------
    FEATURE_KEYS = ("features", "preset")  # config entries that change the learned features

    def learn(self, scene, gaussians, deformation, masks_dir: Path, config: dict, work_dir: Path,
              progress: bool = True) -> tuple[np.ndarray, dict]:
        """Train per-gaussian features [N, D] on frozen geometry -> (features, info)."""
        import masks as masklib
        from trase.features import FeatureConfig, train_features

        work_dir = Path(work_dir)
        masks_dir = Path(masks_dir)
        try:
            fcfg = FeatureConfig(**config["features"])
        except TypeError as exc:
            raise MethodError(f"method.features: {exc}") from None

        def load_masks(view):
            p = masklib.mask_path(masks_dir, view.name)
            if not p.is_file():
                raise MethodError(f"{p}: masks of training view {view.name} not found")
            return masklib.load(p)

        res = train_features(gaussians, deformation, scene.train, load_masks, fcfg,
                             cache_dir=work_dir / "pixel_weights", progress=progress)
        feats = res.features.detach().cpu().numpy().astype(np.float32)
        info = {
            "timings": {"features_prepare": res.timings["prepare"], "features_train": res.timings["train"],
                        "features_per_step": res.timings["per_step"]},
            "path": res.path_stats,
            "loss_tail": res.history[-5:],
            "objective": fcfg.objective,
        }
        return feats, info

    def group(self, feats: np.ndarray, config: dict, gaussians=None, deformation=None,
              learn_info: dict | None = None) -> FittedModel:
        """Cluster features, assign every gaussian, filter by similarity -> FittedModel."""
        from trase.clustering import cluster, filter_by_similarity
        from trase.feature_stats import feature_space_stats

        learn_info = dict(learn_info or {})
        ccfg = config["clustering"]
        t0 = time.perf_counter()
        cl = cluster(feats, method=ccfg["method"], fraction=float(ccfg["fraction"]), seed=int(ccfg["seed"]),
                     min_sample=int(ccfg.get("min_sample", 500)), **ccfg.get("params", {}))
        t_cluster = time.perf_counter() - t0
        keep = filter_by_similarity(feats, cl.labels, float(config["filter_threshold"]))
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
        }
        timings = {**learn_info.get("timings", {}), "clustering": t_cluster}
        return FittedModel(feats, cl.labels, keep, timings, stats, config, gaussians, deformation)

    # -- segment -----------------------------------------------------------------------
    # segment = select clusters by clicks, then render_selection (evaluate re-renders a click
    # set that chose the same clusters from memory)
    selects_clusters = True

    def click_clusters(self, fitted: FittedModel, scene, prompts) -> list[int]:
        """The cluster each prompt click chose, in click order (-1: a click on no surface)."""
        from trase.prompts import click_to_cluster

        pcfg = fitted.config.get("prompts", {})
        min_alpha = float(pcfg.get("min_alpha", 0.5))
        rule, radius = str(pcfg.get("click_rule", "depth")), int(pcfg.get("click_radius", 1))
        out = []
        for c in prompts.clicks:
            view = click_view(scene, prompts, c)
            out.append(int(click_to_cluster(fitted.gaussians, fitted.deformation, view.camera, c, fitted.labels,
                                            min_alpha, rule, radius, features=fitted.features)))
        return out

    def select(self, fitted: FittedModel, scene, prompts) -> list[int]:
        """Prompt clicks -> chosen cluster ids (clicks on no surface choose nothing)."""
        return sorted({k for k in self.click_clusters(fitted, scene, prompts) if k >= 0})

    def segment(self, fitted: FittedModel, scene, prompts) -> list[np.ndarray]:
        """Masks of the test views for the clusters the clicks choose; records the cluster of
        each click (``stats["click_clusters"]``) and the chosen set (``selected_clusters``)."""
        per_click = self.click_clusters(fitted, scene, prompts) if fitted.gaussians is not None else []
        clusters = sorted({k for k in per_click if k >= 0})
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
        thr = float(fitted.config.get("alpha_threshold", 0.5))
        rule = str(fitted.config.get("render_rule", "alone"))
        return render_masks(fitted.gaussians, fitted.deformation, sel, [v.camera for v in scene.test], thr, rule)

    def segment_oracle(self, fitted: FittedModel, scene, gts: list[np.ndarray]) -> tuple[list[np.ndarray], list[int]]:
        """Upper bound: clusters mostly inside the ground truth (all test frames), rendered
        with the same filter. Report separately; never the method's score."""
        from benchmark.protocol.oracle import oracle_clusters
        from trase.segment import render_masks, select_gaussians

        cams = [v.camera for v in scene.test]
        clusters = oracle_clusters(fitted.gaussians, fitted.deformation, cams, gts, fitted.labels)
        sel = select_gaussians(fitted.labels, clusters, fitted.keep)
        thr = float(fitted.config.get("alpha_threshold", 0.5))
        rule = str(fitted.config.get("render_rule", "alone"))
        return render_masks(fitted.gaussians, fitted.deformation, sel, cams, thr, rule), clusters


def click_view(scene, prompts, click):
    """The test view a click was made in (its own frame; else the prompts' first frame)."""
    name = click.view or prompts.view
    index = click.view_index if click.view_index >= 0 else prompts.view_index
    for v in scene.test:
        if v.name == name:
            return v
    if 0 <= index < len(scene.test):
        return scene.test[index]
    raise MethodError(f"prompt view {name!r} is not a test view of {scene.root}")


def with_objective(objective: str, **params) -> TraseMethod:
    """A TRASE pipeline with another objective (for ablations and baselines)."""
    return TraseMethod(objective=objective, objective_params=params)


__all__ = ["TraseMethod", "with_objective"]
