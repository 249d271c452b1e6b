"""Benchmark methods: a registry of ``Method`` classes by name, like nerfbaselines' specs.

A method turns frozen geometry + 2D masks into per-gaussian labels (``fit``), and prompts into
predicted masks at the scene's test views (``segment``)::

    method = get_method("trase")              # or get_method("trase", objective="trase-hard")
    cfg = method.default_config(dataset_spec, "cpu")  # plain JSON-able dict; the runner merges --set
    fitted = method.fit(scene, gaussians, deformation, masks_dir, cfg, work_dir)
    preds = method.segment(fitted, scene, prompts)   # list of bool [H, W], one per scene.test

Method modules are imported lazily: ``get_method`` imports ``benchmark.methods.<module>``
for the built-in names and ``baselines`` for the rest, so listing methods stays cheap.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmark.errors import UserError


class MethodError(UserError):
    """Unknown method or bad method input; one line naming the problem."""


METHODS: dict[str, Callable[..., Method]] = {}
_BUILTIN_MODULES = {"trase": "benchmark.methods.trase_method"}


def register_method(name: str) -> Callable:
    """Class decorator: make a Method constructible by name (``get_method``)."""

    def wrap(cls):
        if name in METHODS and METHODS[name] is not cls:
            raise ValueError(f"method {name!r} registered twice")
        cls.name = name
        METHODS[name] = cls
        return cls

    return wrap


def get_method(name: str, **kwargs) -> Method:
    """Build a registered method; imports the module that registers it on first use."""
    if name not in METHODS:
        modules = [_BUILTIN_MODULES[name]] if name in _BUILTIN_MODULES else []
        modules += list(_BUILTIN_MODULES.values()) + ["baselines.methods", "baselines"]
        for mod in modules:
            try:
                importlib.import_module(mod)
            except ModuleNotFoundError as exc:
                if exc.name is None or not mod.startswith(exc.name):
                    raise
            if name in METHODS:
                break
    if name not in METHODS:
        raise MethodError(f"unknown method {name!r}; known: {', '.join(sorted(METHODS)) or 'none'}")
    return METHODS[name](**kwargs)


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
    """Base class. Subclasses set ``name`` via ``register_method`` and implement the three
    methods; ``segment`` returns one bool [H, W] mask per ``scene.test`` view, in order."""

    name: str = ""

    def default_config(self, dataset_spec, preset: str) -> dict:
        """Plain JSON-able settings for one dataset under ``preset`` (paper or cpu; the run's
        preset, resolved once by the benchmark)."""
        raise NotImplementedError

    def fit(self, scene, gaussians, deformation, masks_dir: Path, config: dict, work_dir: Path,
            progress: bool = True) -> FittedModel:
        raise NotImplementedError

    def segment(self, fitted: FittedModel, scene, prompts) -> list[np.ndarray]:
        raise NotImplementedError


__all__ = ["METHODS", "FittedModel", "Method", "MethodError", "get_method", "register_method"]

# Baseline methods (benchmark/methods/baselines.py), imported lazily like the built-ins.
_BUILTIN_MODULES.update(dict.fromkeys(("trase-hard", "trase-all", "cgc", "opengaussian"), "benchmark.methods.baselines"))
