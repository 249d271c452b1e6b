"""A run's settings, resolved and checked once per sequence into a typed ``RunSettings`` that
the stages read: the run's one preset (``--set preset=P``; auto: paper with a GPU, cpu without)
resolved in the reconstruction's presets and the method's own (lazyspecs.presets), the run seed
written into every seeded section, then the ``--set`` overrides (a misspelt key is an error).

Dicts exist only at the edges: ``RunSettings.to_dict()`` is what results.json records and the
run's name hashes; the stage cache hashes the resolved values of a stage's own section.
"""

from __future__ import annotations

import dataclasses
import sys
from typing import Any

from benchmark import numerics
from benchmark.cache import config_hash
from benchmark.config import ConfigError, flatten, merge, typed
from benchmark.datasets.registry import get_dataset
from benchmark.protocol.settings import PromptProtocol
from lazyspecs.presets import Context, Derived, When
from trase.feature_config import FeatureConfig
from trase.reconstruction_config import ReconstructionConfig
from trase.reconstruction_presets import RECONSTRUCTION_PRESETS

# The benchmark's geometry presets: the reconstruction's, with the public code's per-dataset
# schedule (warm-up, densification end) under ``paper``, as the dataset registry states it.
A_BENCHMARK = When("a benchmark", lambda c: c.dataset is not None)
GEOMETRY_PRESETS = RECONSTRUCTION_PRESETS.extended("geometry")
GEOMETRY_PRESETS.declare("paper", when=A_BENCHMARK,
                         warm_up=Derived(lambda c: get_dataset(c.dataset).warm_up, "the dataset's warm_up (its registry entry)"),
                         densify_until=Derived(lambda c: get_dataset(c.dataset).densify_until,
                                               "the dataset's densify_until (its registry entry)"))

# where the run seed goes: every random choice of the method's pipeline (gaussian
# initialisation and densification, pixel/mask sampling of feature training, the clustering
# sample). The 2D masks are the benchmark's input and keep their own seed (masks.seed).
SEED_PATHS = (("geometry", "train", "seed"), ("method", "features", "seed"), ("method", "clustering", "seed"))


TRACKING = ("none", "synthetic", "files", "classical")  # masks.tracking (benchmark.pipeline.tracks)
SAM_MODELS = ("vit_b", "vit_l", "vit_h")  # masks.checkpoints.SAM_CHECKPOINTS
TRACKING_FIELDS = ("tracking", "tracks_dir")  # recorded only where tracking is on (untracked runs keep their hash)


@dataclasses.dataclass
class MaskSettings:
    generator: str = "classical"  # synthetic | classical | sam (benchmark runs); files (captures)
    checkpoint: str | None = None  # SAM checkpoint path (generator "sam")
    # generator "sam" without a checkpoint: the official one of this model (vit_b, vit_l,
    # vit_h), fetched once into the cache and checked against its SHA-256 (masks.checkpoints)
    model: str | None = None
    seed: int = 0
    # ids consistent across views (masks.tracked): none | synthetic (the synthetic scene's
    # instance maps) | files (tracks_dir, e.g. DEVA's output) | classical (the project's tracker)
    tracking: str = "none"
    tracks_dir: str | None = None  # tracking "files": the folder of per-frame id images

    def __post_init__(self) -> None:
        if self.model is not None and self.model not in SAM_MODELS:
            raise ConfigError(f"--set masks.model={self.model}: choose {', '.join(SAM_MODELS)}")
        if self.tracking not in TRACKING:
            raise ConfigError(f"--set masks.tracking={self.tracking}: choose {', '.join(TRACKING)}")
        if self.tracking == "files" and not self.tracks_dir:
            raise ConfigError("masks.tracking=files needs --set masks.tracks_dir=PATH (a folder of per-frame id "
                              "images, e.g. DEVA's Annotations)")
        if self.tracks_dir and self.tracking != "files":
            raise ConfigError(f"--set masks.tracks_dir: read only with masks.tracking=files (it is {self.tracking})")


def recorded_masks(masks: dict) -> dict:
    """The masks section as a run records and hashes it: the tracking fields only where tracking
    is on, and the SAM model only where one is named, so every run without them keeps the
    config hash, name and stage keys it had before they existed (as plugins' packages are
    keyed only where a plugin is used)."""
    out = dict(masks)
    if out.get("model") is None:
        out.pop("model", None)
    if out.get("tracking", "none") == "none" and out.get("tracks_dir") is None:
        return {k: v for k, v in out.items() if k not in TRACKING_FIELDS}
    return out


# Settings added after runs had been recorded, with the value that does what the code did before
# they existed: where a section holds that value, the setting and the settings that act only
# through it (named exactly) are left out of the run's record, config hash and stage keys, so runs
# that do not use it keep their names and cached stages. Measured: the geometry reconstructed with
# static_threshold 0 and deform_scale_rule "clamp" is bit for bit the geometry of the code before
# those settings (its checksum on all five built-in formats).
def _named(cls, prefix: str) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(cls) if f.name.startswith(prefix))


AS_BEFORE = {
    # stages that stop when converged (trase.convergence): off
    "stop_interval": (0, tuple(dict.fromkeys(_named(ReconstructionConfig, "stop_") + _named(FeatureConfig, "stop_")))),
    "static_threshold": (0.0, _named(ReconstructionConfig, "static_")),  # static gaussians: off
    "static_hold_error": (0.0, ("static_hold_error",)),  # above the time gap, hold every gaussian back
    "deform_scale_rule": ("clamp", ("deform_scale_rule",)),  # the CPU presets' scale rule, the only one before
    "near_plane": (0.01, ("near_plane",)),  # the rasterizer's near plane, the only one before
    # full-size renders and the configured cap throughout (trase.resolution_schedule): both off,
    # and the frequency schedule's settings unread
    "resolution_schedule": ("off", ("resolution_schedule",)),
    "primitive_schedule": ("off", ("primitive_schedule",)),
    ("resolution_schedule", "primitive_schedule"): (("off", "off"), ("resolution_max_factor", "resolution_until")),
    "numerics": ("native", ("numerics",)),  # each library's own kernels for this processor (benchmark.numerics)
    # the first clicks alone (the single-click protocol)
    "corrections": (0, ("corrections", "correction_target", "correction_min_gain", "correction_check_frames")),
    # the benchmark's clicks (not text prompts)
    "source": ("clicks", ("source", "text_detector", "text_segmenter", "text_rule", "text_min_cover", "text_min_share", "text_min_score",
                           "text_file")),
    "correction_min_gain": (0.0, ("correction_min_gain",)),  # any gain in the watched frames keeps a click
    "correction_undone_radius": (0.0, ("correction_undone_radius", "correction_region_tries")),  # an undone click's region left alone
    "correction_region_tries": (0, ("correction_region_tries",)),  # no limit on the clicks undone in a region
    # every gaussian keeps its own feature (trase.unseen): off
    "unseen_min_weight": (0.0, ("unseen_min_weight", "unseen_neighbours")),
    "on_selected": ("nothing", ("on_selected",)),  # a click on a selected cluster adds nothing (trase.prompts)
}


def _as_before(section: dict, key, value) -> bool:
    """Whether ``section`` holds AS_BEFORE's ``value`` for ``key`` (a tuple of keys: all of them)."""
    keys, values = (key, value) if isinstance(key, tuple) else ((key,), (value,))
    return all(k in section and section[k] == v for k, v in zip(keys, values))


def recorded_settings(section):
    """``section`` (nested dicts) as a run records and hashes it: in each dict, the settings of
    AS_BEFORE that hold their "as before" value are left out with those named beside them, and
    so is a section those drops leave empty (``machine`` with native numerics)."""
    if not isinstance(section, dict):
        return section
    dropped = {name for key, (value, names) in AS_BEFORE.items() if _as_before(section, key, value) for name in names}
    out = {k: recorded_settings(v) for k, v in section.items() if k not in dropped}
    return {k: v for k, v in out.items() if v != {} or section[k] == {}}


@dataclasses.dataclass
class MachineSettings:
    """How the run's process computes (benchmark.numerics): "portable" (one x86-64 baseline,
    the same bits on every machine) or "native" (this processor's fastest kernels)."""

    numerics: str = numerics.DEFAULT

    def __post_init__(self) -> None:
        if self.numerics not in numerics.MODES:
            raise ConfigError(f"--set machine.numerics={self.numerics}: choose {' or '.join(numerics.MODES)}")


@dataclasses.dataclass
class CaptureMaskSettings(MaskSettings):
    dir: str | None = None  # generator "files": masks made elsewhere (benchmark.pipeline.masks)


@dataclasses.dataclass
class GeometrySettings:
    source: str = "reconstruct"  # reconstruct | ground-truth (synthetic) | import
    preset: str = "cpu"  # the run's preset, recorded (the cache key hashes ``train`` instead)
    model_dir: str | None = None  # for source=import: a Deformable-3DGS/TRASE model directory
    train: ReconstructionConfig = dataclasses.field(default_factory=ReconstructionConfig)


def key_config(settings) -> dict:
    """What a stage's cache key hashes of a settings section: its resolved values without the
    preset's name, so two presets with the same values share the stage."""
    d = recorded_settings(dataclasses.asdict(settings))
    d.pop("preset", None)
    return d


@dataclasses.dataclass
class RunSettings:
    """Everything one sequence's stages read, resolved once."""

    preset: str  # the run's preset (auto resolved)
    seed: int  # the run seed
    masks: MaskSettings
    geometry: GeometrySettings
    method: Any  # the method's typed settings (its presets' config class)
    prompts: PromptProtocol | None = None  # benchmark runs
    machine: MachineSettings = dataclasses.field(default_factory=MachineSettings)
    capture: dict | None = None  # trase-bench fit: the capture's reading options (CaptureOptions)
    sources: dict[str, str] = dataclasses.field(default_factory=dict)  # dotted setting -> where declared
    group_hash: str = ""  # the config hash without the run seed: one row of a table over seeds
    is_default: bool = False  # no --set changed a setting (the seed aside)

    def to_dict(self) -> dict:
        """The record's form (results.json, the run's name)."""
        out = {"masks": recorded_masks(dataclasses.asdict(self.masks)), "geometry": dataclasses.asdict(self.geometry),
               "method": dataclasses.asdict(self.method)}
        if self.prompts is not None:
            out["prompts"] = dataclasses.asdict(self.prompts)
        if self.capture is not None:
            out["capture"] = dict(self.capture)
        out["seed"] = self.seed
        out["machine"] = dataclasses.asdict(self.machine)
        return recorded_settings(out)


def run_settings(method, spec, variant: str, overrides: dict, image_size: tuple[int, int] | None = None) -> RunSettings:
    """The settings of one benchmark run: ``spec``'s sequence under the run's preset, the run
    seed (``--set seed=S``, written into every seeded section), then ``overrides`` (an explicit
    ``method.features.seed`` still wins). ``image_size`` (W, H) of the benchmark images picks
    the cpu presets' training resolution."""
    masks = {"generator": "synthetic" if variant == "synthetic" else "classical", "checkpoint": None, "seed": 0,
             **_tracking(method)}
    ctx = Context(dataset=spec.key, monocular=spec.monocular, image_size=image_size)
    settings = _resolve(method, ctx, overrides, masks, {"prompts": dataclasses.asdict(PromptProtocol())})
    if settings.masks.tracking == "synthetic" and variant != "synthetic":
        raise ConfigError("masks.tracking=synthetic reads a synthetic scene's instance maps; this scene is real "
                          "(choose classical, or files with masks.tracks_dir)")
    return settings


def capture_settings(method, monocular: bool, capture: dict, overrides: dict,
                     image_size: tuple[int, int] | None = None) -> RunSettings:
    """The settings of ``trase-bench fit`` on a capture of one's own: as a run's, with the
    method's settings for the capture's rig, Deformable-3DGS's default schedule under the paper
    preset, masks by the classical generator (or SAM with --set masks.generator=sam
    masks.checkpoint=PATH, or masks made elsewhere with masks.generator=files masks.dir=PATH),
    and the ``capture`` section (benchmark.captures.CaptureOptions)."""
    masks = {"generator": "classical", "checkpoint": None, "seed": 0, "dir": None, **_tracking(method)}
    ctx = Context(dataset=None, monocular=monocular, image_size=image_size)
    return _resolve(method, ctx, overrides, masks, {"capture": dict(capture)})


def _tracking(method) -> dict:
    """The tracking fields' defaults: none, or the classical tracker for a method that needs
    tracked masks (``Method.needs_tracks``)."""
    return {"tracking": "classical" if getattr(method, "needs_tracks", False) else "none", "tracks_dir": None}


def _resolve(method, ctx: Context, overrides: dict, masks: dict, extra: dict) -> RunSettings:
    overrides = dict(overrides)
    seed = run_seed(overrides)
    ctx = dataclasses.replace(ctx, device=_device_here())
    preset, auto_preset = take_preset(overrides, ctx.device)
    ctx = dataclasses.replace(ctx, objective=flatten(overrides).get("method.features.objective"))  # --set's
    geometry = GEOMETRY_PRESETS.resolve(preset, ctx)
    resolved = method.resolve_settings(preset, ctx)
    asked = overrides.get("method", {}).get("preset") if isinstance(overrides.get("method"), dict) else None
    if asked is not None and asked != resolved.config.preset:
        raise ConfigError(f"--set method.preset={asked}: the method's preset follows the run's "
                          f"(preset={preset} gives {resolved.config.preset}); set --set preset instead")
    base = {"masks": masks,
            "geometry": {"source": "reconstruct", "preset": preset, "model_dir": None,
                         "train": dataclasses.asdict(geometry.config)},
            "method": dataclasses.asdict(resolved.config), "machine": {"numerics": numerics.DEFAULT}, **extra}
    plain = without_seed(overrides)
    cfg = merge(apply_seed(base, seed), plain)
    settings = _typed(method, cfg, preset)
    settings.sources = {**{f"geometry.train.{k}": v for k, v in geometry.sources.items()},
                        **{f"method.{k}": v for k, v in resolved.sources.items()},
                        **{".".join(p): f"the run seed ({seed})" for p in SEED_PATHS},
                        **{k: "--set" for k in flatten(plain)}}
    # the same run without its seed (an explicit seed of one section stays), and without --set
    group = _with_devices(merge(apply_seed(base, 0), plain), settings)
    default = _with_devices(merge(base, {}), settings)
    settings.group_hash = config_hash(recorded_settings({**group, "masks": recorded_masks(group["masks"])}))
    settings.is_default = preset == auto_preset and group == default
    return settings


def _with_devices(cfg: dict, settings: RunSettings) -> dict:
    """``cfg`` with its "auto" devices as ``settings`` resolved them."""
    cfg["geometry"]["train"]["device"] = settings.geometry.train.device
    features = getattr(settings.method, "features", None)
    if hasattr(features, "device") and isinstance(cfg["method"].get("features"), dict):
        cfg["method"]["features"]["device"] = features.device
    return cfg


def _typed(method, cfg: dict, preset: str) -> RunSettings:
    """Every section typed and checked (a wrong value stops the run here, naming the setting),
    devices resolved."""
    masks_cls = CaptureMaskSettings if "dir" in cfg["masks"] else MaskSettings
    geometry = typed(GeometrySettings, cfg["geometry"], "geometry")
    method_settings = typed(method.settings_class(), cfg["method"], "method")
    geometry.train.device = _resolve_device(geometry.train.device, "geometry.train.device")
    features = getattr(method_settings, "features", None)
    if features is not None and hasattr(features, "device"):
        features.device = _resolve_device(features.device, "method.features.device")
    method.check_settings(method_settings)
    masks = typed(masks_cls, cfg["masks"], "masks")
    if getattr(method, "needs_tracks", False) and masks.tracking == "none":
        raise ConfigError(f"method {method.name!r} learns from tracked masks: masks.tracking=none cannot work "
                          "(choose classical, synthetic or files)")
    return RunSettings(preset=preset, seed=cfg["seed"], masks=masks,
                       geometry=geometry, method=method_settings,
                       prompts=typed(PromptProtocol, cfg["prompts"], "prompts") if "prompts" in cfg else None,
                       capture=cfg.get("capture"), machine=typed(MachineSettings, cfg["machine"], "machine"))


# -- the preset -----------------------------------------------------------------------------
def take_preset(overrides: dict, device: str) -> tuple[str, str]:
    """(the run's preset, what auto gives on ``device``), taken out of ``overrides``: ``--set
    preset=P``, or its old spelling ``--set geometry.preset=P`` (with a notice); auto -> paper
    with a GPU, cpu without. Two spellings that disagree are an error."""
    top = overrides.pop("preset", None)
    geometry = overrides.get("geometry")
    old = geometry.pop("preset", None) if isinstance(geometry, dict) else None
    if isinstance(geometry, dict) and not geometry:
        overrides.pop("geometry")
    if old is not None:
        print("trase-bench: --set geometry.preset is now --set preset (the old spelling goes in the next version)",
              file=sys.stderr)
        if top is not None and top != old:
            raise ConfigError(f"--set preset={top} and --set geometry.preset={old} disagree: give one "
                              "(geometry.preset is the old name of preset)")
    asked = top if top is not None else old if old is not None else "auto"
    auto = "paper" if device == "cuda" else "cpu"
    preset = auto if asked == "auto" else asked
    if preset not in GEOMETRY_PRESETS:
        raise ConfigError(f"--set preset={preset}: choose auto, {', '.join(GEOMETRY_PRESETS.names())}")
    return preset, auto


def _device_here() -> str:
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


def _resolve_device(setting: str, name: str) -> str:
    """"auto" -> "cuda" or "cpu" (so a run's record and cache keys say where it computed). CUDA
    rasterizes with gsplat: without it the run stops here, before any stage, rather than at its
    first render."""
    from trase.devices import DeviceError, gsplat_missing, resolve_device

    try:
        device = resolve_device(setting).type
    except DeviceError as exc:
        raise ConfigError(f"--set {name}: {exc}") from None
    why = gsplat_missing(device)
    if why:
        raise ConfigError(f"{name}: {why}; or --set {name}=cpu")
    return device


# -- the run seed ---------------------------------------------------------------------------
def run_seed(overrides: dict) -> int:
    """The run seed of ``--set seed=S`` (default 0), checked."""
    seed = overrides.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"--set seed={seed!r}: the run seed is a whole number >= 0")
    return seed


def apply_seed(cfg: dict, seed: int) -> dict:
    """Write the run seed into every section that has a seed (SEED_PATHS), in place."""
    cfg["seed"] = seed
    for path in SEED_PATHS:
        node = _get(cfg, path[:-1])
        if isinstance(node, dict) and path[-1] in node:
            node[path[-1]] = seed
    return cfg


def without_seed(overrides: dict) -> dict:
    return {k: v for k, v in overrides.items() if k != "seed"}


def _get(d: dict, path: tuple[str, ...]):
    for p in path:
        d = d.get(p) if isinstance(d, dict) else None
    return d


__all__ = ["GEOMETRY_PRESETS", "SEED_PATHS", "TRACKING", "CaptureMaskSettings", "GeometrySettings", "MachineSettings",
           "MaskSettings",
           "PromptProtocol", "RunSettings", "apply_seed", "capture_settings", "key_config", "recorded_masks",
           "recorded_settings", "run_seed",
           "run_settings", "take_preset", "without_seed"]
