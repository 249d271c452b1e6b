"""Benchmark methods: a registry of ``Method`` classes by name, like nerfbaselines' specs.

A method turns frozen geometry + 2D masks into per-gaussian labels in two halves, ``learn``
(features: the slow part) and ``group`` (clusters and the filter), which the benchmark caches
as two stages so a clustering change reuses the features; and prompts into predicted masks at
the scene's test views (``segment``)::

    method = get_method("trase")              # or get_method("trase", objective="trase-hard")
    settings = method.resolve_settings("cpu", Context(dataset="hypernerf")).config  # typed
    fitted = method.fit(scene, gaussians, deformation, masks_dir, settings, work_dir)  # learn + group
    preds = method.segment(fitted, scene, prompts)   # list of bool [H, W], one per scene.test

A method declares its settings as presets (``presets``, a lazyspecs.presets.PresetTable of its
typed settings class), beside the method. Method modules are imported lazily: ``METHODS`` names
each method's class by its import path (lazyspecs), so listing methods stays cheap.

Other packages add methods through the entry-point group ``trase_bench.methods`` (``name =
module:MethodSubclass``; docs/methods.md): the same registry reads them the first time a name
is not a built-in one, and ``trase-bench methods`` lists both with where each comes from.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from benchmark.errors import UserError
from lazyspecs import Registry, describe
from lazyspecs.presets import Context, PresetTable, Resolved, build


class MethodError(UserError):
    """Unknown method or bad method input; one line naming the problem."""


ENTRY_POINT_GROUP = "trase_bench.methods"  # where installed packages declare their methods
RUN_TIERS = ("paper", "cpu")  # the method presets a run's preset resolves to (trase.reconstruction_presets tiers)


def check_method_class(obj) -> str | None:
    """What keeps a plugin's object from being run as a method (a phrase), or None."""
    if not (isinstance(obj, type) and issubclass(obj, Method)):
        return f"{describe(obj)} is not a subclass of benchmark.methods.Method"
    if not isinstance(obj.presets, PresetTable):
        return (f"class {obj.__qualname__} declares no presets (Method.presets: a lazyspecs.presets.PresetTable "
                "of its settings class)")
    missing = [t for t in RUN_TIERS if t not in obj.presets]
    if missing:
        return (f"class {obj.__qualname__} declares no {' or '.join(repr(t) for t in missing)} preset "
                f"(every run resolves one of {', '.join(RUN_TIERS)})")
    todo = [m for m in ("learn", "group", "segment") if getattr(obj, m) is getattr(Method, m)]
    if todo:
        return f"class {obj.__qualname__} does not implement {', '.join(todo)}"
    return None


METHODS = Registry("method", MethodError, group=ENTRY_POINT_GROUP, check=check_method_class)
METHODS.add("trase", "benchmark.methods.trase_method:TraseMethod", "soft-mined contrastive objective (TRASE)")
METHODS.add("trase-hard", "benchmark.methods.baselines:TraseHardMethod", "hard mining (the paper's ablation)")
METHODS.add("trase-all", "benchmark.methods.baselines:TraseAllMethod", "all mining (the paper's ablation)")
METHODS.add("cgc", "benchmark.methods.baselines:CGCMethod", "Contrastive Gaussian Clustering objective and inference")
METHODS.add("opengaussian", "benchmark.methods.baselines:OpenGaussianMethod", "OpenGaussian-style intra/inter-mask objective")


CHECKPOINT_SECONDS_ENV = "TRASE_CHECKPOINT_SECONDS"


def checkpoint_seconds(default: float = 30.0) -> float:
    """How often a method's long training saves its state for a resume inside the stage
    (seconds; ``$TRASE_CHECKPOINT_SECONDS``). It changes no result: a resumed run continues bit
    for bit."""
    import os

    raw = os.environ.get(CHECKPOINT_SECONDS_ENV)
    if raw is None or raw.strip() == "":
        return default
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not value > 0:
        raise MethodError(f"${CHECKPOINT_SECONDS_ENV}={raw!r}: give seconds > 0")
    return value


def check_clustering(clustering) -> None:
    """ConfigError for a method's ``clustering`` settings (method, params) that
    trase.clustering.cluster would refuse: said before any stage, not after the features."""
    from benchmark.config import ConfigError
    from trase.clustering import ClusteringError, check_params

    try:
        check_params(str(clustering.method), dict(clustering.params))
    except ClusteringError as e:
        raise ConfigError(f"--set method.clustering: {e}") from None


def register_method(name: str) -> Callable:
    """Class decorator: name a Method class (``cls.name``) and register it (``get_method``)."""

    def wrap(cls):
        cls.name = name
        return METHODS.register(name)(cls)

    return wrap


def get_method(name: str, **kwargs) -> Method:
    """Build a registered method (built-in or from a package); its module is imported on first
    use. The instance carries the name it was asked by (``method.name``), which keys its stages
    and its runs. A name ending in ``.toml`` is a method in its own environment, defined by that
    file (benchmark.methods.command)."""
    if name.endswith(".toml"):
        from benchmark.methods.command import load_command_method

        return load_command_method(name, **kwargs)
    method = METHODS.load(name)(**kwargs)
    method.name = name
    return method


@dataclasses.dataclass
class FittedModel:
    """What ``fit`` produces: per-gaussian features and cluster labels, the filter's keep mask,
    plus timings and stats for the results file. Geometry is held by reference, not copied."""

    features: np.ndarray  # [N, D] float32 (saved form: smoothed)
    labels: np.ndarray  # [N] int64 cluster ids 0..C-1
    keep: np.ndarray  # [N] bool: passes the similarity filter
    timings: dict  # seconds per phase
    stats: dict  # n_clusters, feature-space stats, fast-path bytes, loss history tail...
    config: Any  # the method's typed settings (a dict where loaded without its settings class)
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
        config = dataclasses.asdict(self.config) if dataclasses.is_dataclass(self.config) else self.config
        (out / "fitted.json").write_text(json.dumps(
            {"timings": self.timings, "stats": self.stats, "config": config}, indent=1, default=float))

    @classmethod
    def load(cls, out_dir: str | Path, gaussians=None, deformation=None, config_cls: type | None = None) -> FittedModel:
        """A saved model; its settings typed as ``config_cls`` (the method's settings class) if given."""
        out = Path(out_dir)
        need = ["features.npy", "clusters.npy", "keep.npy", "fitted.json"]
        missing = [n for n in need if not (out / n).is_file()]
        if missing:
            raise MethodError(f"{out}: not a fitted model directory (missing {', '.join(missing)})")
        meta = json.loads((out / "fitted.json").read_text())
        config = meta.get("config", {})
        if config_cls is not None:
            config = build(config_cls, config)
        return cls(np.load(out / "features.npy"), np.load(out / "clusters.npy"), np.load(out / "keep.npy"),
                   meta.get("timings", {}), meta.get("stats", {}), config, gaussians, deformation)


class Method:
    """Base class. Subclasses set ``name`` via ``register_method``, declare ``presets`` (their
    typed settings per preset, benchmark and rig) and implement ``learn``, ``group`` and
    ``segment``; ``segment`` returns one bool [H, W] mask per ``scene.test`` view, in order."""

    name: str = ""
    presets: PresetTable | None = None  # the method's settings, declared as data
    # the settings sections (dataclass fields of the settings) that change what ``learn``
    # produces: the features stage's cache key; None: every setting (safe, but a change of a
    # grouping or prompt setting then trains the features again)
    FEATURE_FIELDS: tuple[str, ...] | None = None
    # True: ``learn`` reads tracked masks (ids consistent across views, masks.tracked) from its
    # masks folder; the run then tracks them (masks.tracking, default classical; none refused)
    needs_tracks: bool = False
    # True: the method takes negative clicks (a click's ``positive`` False removes what it
    # points at); the benchmark's corrective clicks then include negative ones. False: positive
    # corrections only, and the run's protocol label says so. None (undeclared): True for a
    # method with a click_selection of its own (takes_negative_clicks)
    negative_clicks: bool | None = None
    # which stages its runs take (benchmark.runner.STAGE_PLANS): "benchmark" (masks, geometry,
    # features and fit, prompts, evaluate, ceiling) or "command" (a method in its own environment)
    stage_plan: str = "benchmark"

    def settings_class(self) -> type:
        if self.presets is None:
            raise MethodError(f"method {self.name!r} declares no presets")
        return self.presets.config_cls

    def resolve_settings(self, preset: str, ctx: Context) -> Resolved:
        """The method's settings under the run's ``preset`` in ``ctx``, with where each was
        declared. A run preset the method does not declare (an earlier CPU geometry preset)
        resolves its tier, paper or cpu, as the reconstruction's presets name it."""
        from trase.reconstruction_presets import RECONSTRUCTION_PRESETS

        if self.presets is None:
            raise MethodError(f"method {self.name!r} declares no presets")
        tier = RECONSTRUCTION_PRESETS.preset(preset).tier if preset in RECONSTRUCTION_PRESETS else None
        return self.presets.resolve(preset, ctx, tier)

    def settings(self, preset: str, dataset: str | None = None, monocular: bool | None = None):
        """The typed settings under ``preset`` for benchmark ``dataset`` (None: a capture of
        one's own, monocular unless told), as a run resolves them before its --set values."""
        from benchmark.datasets.registry import get_dataset

        if monocular is None:
            monocular = get_dataset(dataset).monocular if dataset is not None else True
        return self.resolve_settings(preset, Context(dataset=dataset, monocular=monocular)).config

    def check_settings(self, settings) -> None:
        """Raise ConfigError for settings that cannot work together (the run checks them once,
        before any stage runs); the base class checks nothing."""

    def learn(self, scene, gaussians, deformation, masks_dir: Path, config, work_dir: Path,
              progress: bool = True) -> tuple[np.ndarray, dict]:
        """Per-gaussian features [N, D] float32 and a JSON-able info dict for ``group``."""
        raise NotImplementedError

    def group(self, feats: np.ndarray, config, gaussians=None, deformation=None,
              learn_info: dict | None = None) -> FittedModel:
        """Features -> clusters, filter and stats."""
        raise NotImplementedError

    def group_inputs(self, scene, gaussians, deformation, config) -> dict:
        """What ``group`` reads from the scene beyond the features, added to its ``learn_info``
        (computed in the fit stage, never cached with the features); the base class reads none."""
        return {}

    def fit(self, scene, gaussians, deformation, masks_dir: Path, config, work_dir: Path,
            progress: bool = True) -> FittedModel:
        """``learn`` then ``group`` in one call (the benchmark runs them as two cached stages)."""
        feats, info = self.learn(scene, gaussians, deformation, masks_dir, config, work_dir, progress)
        return self.group(feats, config, gaussians, deformation,
                          {**info, **self.group_inputs(scene, gaussians, deformation, config)})

    def segment(self, fitted: FittedModel, scene, prompts) -> list[np.ndarray]:
        raise NotImplementedError

    def segment_oracle(self, fitted: FittedModel, scene, gts: list[np.ndarray]
                       ) -> tuple[list[np.ndarray], list[int]] | None:
        """Masks and clusters chosen with the ground truth (an upper bound, never the method's
        score); None for a method that has no such bound."""
        return None


def takes_negative_clicks(method) -> bool:
    """Whether a method takes negative clicks: it declares ``negative_clicks``, or (a method
    written before the declaration) has a ``click_selection`` of its own and declares nothing."""
    declared = getattr(method, "negative_clicks", None)
    if declared is None:
        return getattr(method, "click_selection", None) is not None
    return bool(declared)


def click_selection(method, fitted, scene, prompts) -> tuple[list[int], list[int]]:
    """(the clusters selected, the cluster of each click in order) of a method that selects
    clusters: its own ``click_selection`` where it has one, else the clusters of its clicks
    (``click_clusters``) taken in order, a positive click's added unless a negative click
    removed it before, a negative click's removed and kept out. Negative clicks reach only a
    method that declares them (``negative_clicks``)."""
    if any(not c.positive for c in prompts.clicks) and not takes_negative_clicks(method):
        raise MethodError(f"method {method.name!r} takes positive clicks only (it declares no negative_clicks)")
    own = getattr(method, "click_selection", None)
    if own is not None:
        return own(fitted, scene, prompts)
    return combine_clicks(prompts.clicks, method.click_clusters(fitted, scene, prompts))


def combine_clicks(clicks, per_click: list[int]) -> tuple[list[int], list[int]]:
    """(the clusters selected, ``per_click``) from each click's cluster, taken in order: a
    positive click's added unless a negative click ruled it out before, a negative click's
    removed and ruled out."""
    selected: set[int] = set()
    ruled_out: set[int] = set()
    for click, k in zip(clicks, per_click):
        if k < 0:
            continue
        if click.positive and k not in ruled_out:
            selected.add(k)
        elif not click.positive:
            selected.discard(k)
            ruled_out.add(k)
    return sorted(selected), list(per_click)


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


__all__ = ["ENTRY_POINT_GROUP", "METHODS", "FittedModel", "Method", "MethodError", "check_clustering",
           "check_method_class", "click_selection", "click_view", "combine_clicks", "get_method", "register_method", "takes_negative_clicks"]
