"""``saga``: SAGA-style scale-gated affinity features on the benchmark's frozen geometry.

``learn`` trains per-gaussian features and the scale gate from the run's anything-masks, each
mask's 3D scale taken from the geometry's rendered depth (``train``). ``group`` runs SAGA's
clustering mode at the inference scale (the oracle's clusters). ``segment`` is SAGA's click
inference: the feature rendered under each click, gated at the scale, against every
gaussian's gated feature, cosine above the threshold (``inference``); the selection is rendered
at the test views as the other methods render theirs.

Imports at the top are light (``trase-bench methods`` imports this module).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from benchmark.methods import FittedModel, Method, MethodError, click_view
from trase_bench_saga.settings import SAGA_PRESETS, SagaSettings


class SagaMethod(Method):
    """SAGA-style scale-gated contrastive features; a click selects by gated affinity at a scale."""

    presets = SAGA_PRESETS
    FEATURE_FIELDS = ("features",)

    def check_settings(self, settings: SagaSettings) -> None:
        from benchmark.config import ConfigError
        from benchmark.methods import check_clustering

        check_clustering(settings.clustering)

        f, inf = settings.features, settings.inference
        if f.norm_pixels not in ("image", "sampled"):
            raise ConfigError(f"method.features.norm_pixels={f.norm_pixels!r}: choose image or sampled")
        if f.dim < 1 or f.n_rays < 1 or f.n_scales < 0:
            raise ConfigError("method.features: dim and n_rays must be at least 1, n_scales at least 0")
        if not 0.0 <= inf.scale <= 1.0:
            raise ConfigError(f"method.inference.scale={inf.scale}: a quantile in [0, 1]")
        if not -1.0 <= inf.threshold <= 1.0:
            raise ConfigError(f"method.inference.threshold={inf.threshold}: a cosine in [-1, 1]")
        if settings.render_rule not in ("alone", "visible"):
            raise ConfigError(f"method.render_rule={settings.render_rule!r}: choose alone or visible")

    def learn(self, scene, gaussians, deformation, masks_dir: Path, config: SagaSettings, work_dir: Path,
              progress: bool = True) -> tuple[np.ndarray, dict]:
        import masks as masklib
        from trase_bench_saga.train import train_saga

        masks_dir = Path(masks_dir)

        def load_masks(view):
            p = masklib.mask_path(masks_dir, view.name)
            if not p.is_file():
                raise MethodError(f"{p}: masks of training view {view.name} not found")
            return masklib.load(p)

        res = train_saga(gaussians, deformation, scene.train, load_masks, config.features,
                         cache_dir=Path(work_dir) / "pixel_weights", progress=progress)
        info = {
            "timings": {"features_scales": res.timings["scales"], "features_prepare": res.timings["prepare"],
                        "features_train": res.timings["train"], "features_per_step": res.timings["per_step"]},
            "saga": {"gate": res.gate, "quantiles": res.quantiles, "upper_scale": res.upper_scale,
                     "mask_scales": res.scale_stats},
            "path": res.path_stats,
            "loss_tail": res.history[-5:],
        }
        return res.features.numpy().astype(np.float32), info

    def group(self, feats: np.ndarray, config: SagaSettings, gaussians=None, deformation=None,
              learn_info: dict | None = None) -> FittedModel:
        from trase.clustering import cluster
        from trase_bench_saga.inference import gated
        from trase_bench_saga.objective import gate_from_dict

        learn_info = dict(learn_info or {})
        saga = learn_info.get("saga")
        if not saga:
            raise MethodError("saga: the features stage recorded no scale gate (features from another method?)")
        gates = gate_from_dict(saga["gate"], float(config.inference.scale))
        c = config.clustering
        t0 = time.perf_counter()
        cl = cluster(gated(feats, gates).astype(np.float32), method=c.method, fraction=float(c.fraction),
                     seed=int(c.seed), min_sample=int(c.min_sample), **c.params)
        stats = {"n_gaussians": int(feats.shape[0]), "n_clusters": cl.n_clusters, "kept_fraction": 1.0,
                 "saga": saga, "gates": [float(g) for g in gates], "path": learn_info.get("path", {}),
                 "loss_tail": learn_info.get("loss_tail", [])}
        timings = {**learn_info.get("timings", {}), "clustering": time.perf_counter() - t0}
        return FittedModel(feats, cl.labels, np.ones(feats.shape[0], bool), timings, stats, config,
                           gaussians, deformation)

    selects_clusters = False  # a click selects gaussians by affinity, not clusters
    negative_clicks = False  # the selection is a union of affinity queries: positive clicks only

    def _gates(self, fitted: FittedModel) -> np.ndarray:
        from trase_bench_saga.objective import gate_from_dict

        saga = fitted.stats.get("saga") if isinstance(fitted.stats, dict) else None
        if not saga:
            raise MethodError("saga: the fitted model carries no scale gate (fitted.json stats.saga)")
        cfg = fitted.config
        scale = cfg.inference.scale if hasattr(cfg, "inference") else cfg["inference"]["scale"]
        return gate_from_dict(saga["gate"], float(scale))

    def select(self, fitted: FittedModel, scene, prompts) -> np.ndarray:
        """[N] bool: the gaussians the clicks select (union over clicks)."""
        from trase_bench_saga.inference import rendered_feature, select_by_query

        inf = fitted.config.inference
        queries, hits = [], []
        for c in prompts.clicks:
            cam = click_view(scene, prompts, c).camera
            cam = cam if c.time is None else cam.with_time(c.time)
            q = rendered_feature(fitted.gaussians, fitted.deformation, cam, c.u, c.v, fitted.features,
                                 float(inf.min_alpha), int(inf.click_radius))
            hits.append(q is not None)
            if q is not None:
                queries.append(q)
        sel = select_by_query(fitted.features, self._gates(fitted), queries, float(inf.threshold))
        fitted.stats["clicks_on_surface"] = hits
        fitted.stats["selected_gaussians"] = int(sel.sum())
        return sel

    def segment(self, fitted: FittedModel, scene, prompts) -> list[np.ndarray]:
        from trase.segment import render_masks

        if fitted.gaussians is None:
            raise MethodError("saga: segment needs the fitted model's geometry (FittedModel.gaussians is None)")
        sel = self.select(fitted, scene, prompts)
        cfg = fitted.config
        return render_masks(fitted.gaussians, fitted.deformation, sel, [v.camera for v in scene.test],
                            float(cfg.alpha_threshold), str(cfg.render_rule))

    def segment_oracle(self, fitted: FittedModel, scene, gts: list[np.ndarray]):
        """SAGA's clusters at the inference scale mostly inside the ground truth, rendered as
        segment() renders: an upper bound beside the score, never the score."""
        from benchmark.protocol.oracle import oracle_clusters
        from trase.segment import render_masks, select_gaussians

        cams = [v.camera for v in scene.test]
        clusters = oracle_clusters(fitted.gaussians, fitted.deformation, cams, gts, fitted.labels)
        sel = select_gaussians(fitted.labels, clusters, fitted.keep)
        cfg = fitted.config
        return render_masks(fitted.gaussians, fitted.deformation, sel, cams, float(cfg.alpha_threshold),
                            str(cfg.render_rule)), list(clusters)
