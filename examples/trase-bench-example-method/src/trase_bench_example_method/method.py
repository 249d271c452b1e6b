"""``colour-kmeans``: k-means on the gaussians' colours and canonical positions.

A baseline that learns nothing: each gaussian is described by its view-independent colour and
its standardised canonical position, and k-means groups them. A click chooses the cluster
rendered most under it (``trase.prompts`` rule "weight"); the chosen clusters, rendered at the
test views, are the predicted masks. It ignores the benchmark's 2D masks, which is what makes
it a floor for methods that learn from them.

Imports at the top are light (the listing, ``trase-bench methods``, imports this module);
torch, scikit-learn and the renderer are imported inside the methods that use them.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from benchmark.methods import FittedModel, Method, MethodError, click_selection, click_view
from lazyspecs.presets import MONOCULAR, MULTIVIEW, PresetTable


@dataclasses.dataclass
class Description:
    """What ``learn`` makes of each gaussian (the features stage's cache key: FEATURE_FIELDS)."""

    # weight of the standardised canonical position against the colour (RGB in [0, 1]);
    # 0: colour alone
    position_weight: float = 0.25


@dataclasses.dataclass
class KMeansSettings:
    n_clusters: int = 16
    n_init: int = 4  # k-means restarts; the best inertia wins
    seed: int = 0  # the run seed is written here (--set seed=S: method.clustering.seed)


@dataclasses.dataclass
class ColourKMeansSettings:
    """Everything the method reads; runs record it under ``method``, ``--set method.X=...`` sets it."""

    preset: str = "paper"  # the method's preset these settings start from (paper or cpu)
    features: Description = dataclasses.field(default_factory=Description)
    clustering: KMeansSettings = dataclasses.field(default_factory=KMeansSettings)
    min_alpha: float = 0.5  # a click on less rendered alpha than this chooses nothing
    click_radius: int = 1  # the click's window: (2 r + 1)^2 pixels
    alpha_threshold: float = 0.5  # rendered alpha of the selection >= this is the predicted mask
    render_rule: str = "alone"  # trase.segment: "alone" (selection rendered alone) or "visible"


# The presets: every run resolves "paper" (on a GPU) or "cpu" (on a CPU); a value is declared
# with the condition it applies under, and `trase-bench presets --method colour-kmeans
# --dataset D` shows where each came from.
PRESETS = PresetTable("colour-kmeans", ColourKMeansSettings, error=MethodError)
PRESETS.declare("paper", help="k-means with 16 clusters (monocular) or 32 (multi-view)", preset="paper")
# a multi-view rig sees the whole room: more surfaces to tell apart than one moving camera does
PRESETS.declare("paper", {"clustering.n_clusters": 32}, when=MULTIVIEW)
PRESETS.declare("cpu", base="paper", help="as paper; on a monocular rig the selection's visible part is the mask",
                preset="cpu")
# the reason of TRASE's cpu preset: one moving camera on a CPU-sized reconstruction leaves
# gaussians beyond an object's outline where the background hides them
PRESETS.declare("cpu", when=MONOCULAR, render_rule="visible")


class ColourKMeans(Method):
    """k-means on the gaussians' colours and positions; a click picks the cluster under it."""

    presets = PRESETS
    FEATURE_FIELDS = ("features",)  # only the description changes what learn() makes

    def check_settings(self, settings: ColourKMeansSettings) -> None:
        from benchmark.config import ConfigError

        if settings.clustering.n_clusters < 1:
            raise ConfigError(f"method.clustering.n_clusters={settings.clustering.n_clusters}: at least 1")
        if settings.render_rule not in ("alone", "visible"):
            raise ConfigError(f"method.render_rule={settings.render_rule!r}: choose alone or visible")

    def learn(self, scene, gaussians, deformation, masks_dir: Path, config: ColourKMeansSettings,
              work_dir: Path, progress: bool = True) -> tuple[np.ndarray, dict]:
        """[N, 6] float32: RGB and position_weight x the standardised canonical position."""
        t0 = time.perf_counter()
        rgb = gaussians.colors_dc.detach().cpu().numpy().clip(0.0, 1.0)
        xyz = gaussians.means.detach().cpu().numpy().astype(np.float64)
        xyz = (xyz - xyz.mean(axis=0)) / (xyz.std(axis=0) + 1e-12)
        feats = np.concatenate([rgb, config.features.position_weight * xyz], axis=1).astype(np.float32)
        return feats, {"timings": {"describe": time.perf_counter() - t0}}

    def group(self, feats: np.ndarray, config: ColourKMeansSettings, gaussians=None, deformation=None,
              learn_info: dict | None = None) -> FittedModel:
        from sklearn.cluster import KMeans

        t0 = time.perf_counter()
        k = min(int(config.clustering.n_clusters), len(feats))
        km = KMeans(n_clusters=k, n_init=int(config.clustering.n_init), random_state=int(config.clustering.seed))
        labels = km.fit_predict(feats.astype(np.float64)).astype(np.int64)
        keep = np.ones(len(labels), bool)  # every gaussian keeps its cluster: no filter
        timings = {**(learn_info or {}).get("timings", {}), "kmeans": time.perf_counter() - t0}
        stats = {"n_gaussians": len(labels), "n_clusters": k, "inertia": float(km.inertia_)}
        return FittedModel(feats, labels, keep, timings, stats, config, gaussians, deformation)

    # segment() = click_clusters() then render_selection(); declaring both with
    # selects_clusters lets the benchmark render each other click set's clusters once
    selects_clusters = True
    # negative_clicks: a negative click removes the cluster it reads and keeps it out
    # (benchmark.methods.click_selection's rule for methods that select clusters)
    negative_clicks = True

    def click_clusters(self, fitted: FittedModel, scene, prompts) -> list[int]:
        """The cluster rendered most under each click (-1: a click on no surface)."""
        from trase.prompts import click_to_cluster

        cfg = fitted.config
        return [int(click_to_cluster(fitted.gaussians, fitted.deformation, click_view(scene, prompts, c).camera, c,
                                     fitted.labels, float(cfg.min_alpha), "weight", int(cfg.click_radius)))
                for c in prompts.clicks]

    def render_selection(self, fitted: FittedModel, scene, clusters: list[int]) -> list[np.ndarray]:
        from trase.segment import render_masks, select_gaussians

        selected = select_gaussians(fitted.labels, clusters, fitted.keep)
        cfg = fitted.config
        return render_masks(fitted.gaussians, fitted.deformation, selected, [v.camera for v in scene.test],
                            float(cfg.alpha_threshold), str(cfg.render_rule))

    def segment(self, fitted: FittedModel, scene, prompts) -> list[np.ndarray]:
        """One bool [H, W] mask per test view: the clusters the clicks chose."""
        if fitted.gaussians is None:
            raise MethodError("colour-kmeans needs the fitted model's geometry to segment")
        clusters, per_click = click_selection(self, fitted, scene, prompts)  # negative clicks remove
        fitted.stats["click_clusters"], fitted.stats["selected_clusters"] = per_click, clusters
        return self.render_selection(fitted, scene, clusters)

    def segment_oracle(self, fitted: FittedModel, scene, gts: list[np.ndarray]):
        """The clusters mostly inside the ground truth, rendered as segment() renders (an upper
        bound the results show beside the score, never the method's score)."""
        from benchmark.protocol.oracle import oracle_clusters

        cams = [v.camera for v in scene.test]
        clusters = oracle_clusters(fitted.gaussians, fitted.deformation, cams, gts, fitted.labels)
        return self.render_selection(fitted, scene, list(clusters)), list(clusters)
