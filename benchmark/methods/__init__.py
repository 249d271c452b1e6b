"""Benchmark methods: a registry of ``Method`` classes by name, like nerfbaselines' specs.

A method turns frozen geometry + 2D masks into per-gaussian labels in two halves, ``learn``
(features: the slow part) and ``group`` (clusters and the filter), which the benchmark caches
as two stages so a clustering change reuses the features; and prompts into predicted masks at
the scene's test views (``segment``)::

    method = get_method("trase")              # or get_method("trase", objective="trase-hard")
    cfg = method.default_config("hypernerf", "cpu")   # plain JSON-able dict; --set merges into it
    fitted = method.fit(scene, gaussians, deformation, masks_dir, cfg, work_dir)  # learn + group
    preds = method.segment(fitted, scene, prompts)   # list of bool [H, W], one per scene.test

Method modules are imported lazily: ``METHODS`` names each method's class by its import path
(lazyspecs), so listing methods stays cheap.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmark.errors import UserError
from lazyspecs import Registry


class MethodError(UserError):
    """Unknown method or bad method input; one line naming the problem."""


METHODS = Registry("method", MethodError)
METHODS.add("trase", "benchmark.methods.trase_method:TraseMethod", "soft-mined contrastive objective (TRASE)")
METHODS.add("trase-hard", "benchmark.methods.baselines:TraseHardMethod", "hard mining (the paper's ablation)")
METHODS.add("trase-all", "benchmark.methods.baselines:TraseAllMethod", "all mining (the paper's ablation)")
METHODS.add("cgc", "benchmark.methods.baselines:CGCMethod", "Contrastive Gaussian Clustering objective and inference")
METHODS.add("opengaussian", "benchmark.methods.baselines:OpenGaussianMethod", "OpenGaussian-style intra/inter-mask objective")


def register_method(name: str) -> Callable:
    """Class decorator: name a Method class (``cls.name``) and register it (``get_method``)."""

    def wrap(cls):
        cls.name = name
        return METHODS.register(name)(cls)

    return wrap


def get_method(name: str, **kwargs) -> Method:
    """Build a registered method; its module is imported on first use."""
    return METHODS.load(name)(**kwargs)


@dataclasses.dataclass
class FittedModel:
    """What ``fit`` produces: per-gaussian features and cluster labels, the filter's keep mask,
    plus timings and stats for the results file. Geometry is held by reference, not copied."""

    features: np.ndarray  # [N, D] float32 (saved form: smoothed)
    labels: np.ndarray  # [N] int64 cluster ids 0..C-1
    keep: np.ndarray  # [N] bool: passes the similarity filter
    timings: dict  # seconds per phase
    stats: dict  # n_clusters, feature-space stats, fast-path bytes, loss history tail...
    config: dict
    gaussians: object = None
    deformation: object = None

    def save(self, out_dir: str | Path) -> None:
        """features.npy, clusters.npy, keep.npy, fitted.json (+ PLY/clusters.pt via trase.export)."""
        from trase.export import export_clusters, export_ply

        out = Path(out_dir)
        export_clusters(out, self.labels, self.features)
        np.save(out / "keep.npy", np.asarray(self.keep, bool))
        if self.gaussians is not None:
            export_ply(self.gaussians, self.features, out / "point_cloud.ply", labels=self.labels)
        (out / "fitted.json").write_text(json.dumps(
            {"timings": self.timings, "stats": self.stats, "config": self.config}, indent=1, default=float))

    @classmethod
    def load(cls, out_dir: str | Path, gaussians=None, deformation=None) -> FittedModel:
        out = Path(out_dir)
        need = ["features.npy", "clusters.npy", "keep.npy", "fitted.json"]
        missing = [n for n in need if not (out / n).is_file()]
        if missing:
            raise MethodError(f"{out}: not a fitted model directory (missing {', '.join(missing)})")
        meta = json.loads((out / "fitted.json").read_text())
        return cls(np.load(out / "features.npy"), np.load(out / "clusters.npy"), np.load(out / "keep.npy"),
                   meta.get("timings", {}), meta.get("stats", {}), meta.get("config", {}), gaussians, deformation)


class Method:
    """Base class. Subclasses set ``name`` via ``register_method`` and implement
    ``default_config``, ``learn``, ``group`` and ``segment``; ``segment`` returns one bool
    [H, W] mask per ``scene.test`` view, in order."""

    name: str = ""
    FEATURE_KEYS: tuple[str, ...] = ()  # config entries that change what ``learn`` produces

    def default_config(self, dataset: str | None, preset: str, monocular: bool = True) -> dict:
        """Plain JSON-able settings for benchmark ``dataset`` (None: a capture of one's own,
        described by its rig) under ``preset`` (paper or cpu, resolved once by the benchmark)."""
        raise NotImplementedError

    def check_config(self, config: dict) -> None:
        """Raise ConfigError for a setting of the wrong type (the run config checks it once,
        before any stage runs); the base class checks nothing."""

    def learn(self, scene, gaussians, deformation, masks_dir: Path, config: dict, work_dir: Path,
              progress: bool = True) -> tuple[np.ndarray, dict]:
        """Per-gaussian features [N, D] float32 and a JSON-able info dict for ``group``."""
        raise NotImplementedError

    def group(self, feats: np.ndarray, config: dict, gaussians=None, deformation=None,
              learn_info: dict | None = None) -> FittedModel:
        """Features -> clusters, filter and stats."""
        raise NotImplementedError

    def fit(self, scene, gaussians, deformation, masks_dir: Path, config: dict, work_dir: Path,
            progress: bool = True) -> FittedModel:
        """``learn`` then ``group`` in one call (the benchmark runs them as two cached stages)."""
        feats, info = self.learn(scene, gaussians, deformation, masks_dir, config, work_dir, progress)
        return self.group(feats, config, gaussians, deformation, info)

    def segment(self, fitted: FittedModel, scene, prompts) -> list[np.ndarray]:
        raise NotImplementedError

    def segment_oracle(self, fitted: FittedModel, scene, gts: list[np.ndarray]
                       ) -> tuple[list[np.ndarray], list[int]] | None:
        """Masks and clusters chosen with the ground truth (an upper bound, never the method's
        score); None for a method that has no such bound."""
        return None


__all__ = ["METHODS", "FittedModel", "Method", "MethodError", "get_method", "register_method"]
