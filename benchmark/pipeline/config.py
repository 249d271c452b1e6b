"""The run's config, resolved once: dataset and variant defaults, the preset, the run seed
written into every seeded section, then the ``--set`` overrides (a misspelt key is an error)."""

from __future__ import annotations

from benchmark.config import ConfigError, merge, typed

CPU_TRAIN_MAX_SIDE = 480  # px: the cpu preset's geometry trains at most this large


def cpu_train_downscale(image_size: tuple[int, int] | None) -> float:
    """Power-of-two factor bringing the (W, H) benchmark images to at most CPU_TRAIN_MAX_SIDE.

    Why not always downscale: the geometry is rendered at full resolution for evaluation, and
    gaussians fitted at half resolution leave holes there (synthetic HyperNeRF 160x120,
    `trase-bench perf reconstruct`, 2000 iterations: 18.6 dB test PSNR at full resolution when
    trained at half, 24.7 dB when trained at full (3000-step LR decay), in 125 s vs 135 s: an
    iteration costs nearly the same at this size, the deformation MLP over the gaussians
    dominating). Real images (960x536 and up) are still reduced, where per-pixel work
    dominates.
    """
    if not image_size:
        return 1.0
    side, ds = max(image_size), 1
    while side / ds > CPU_TRAIN_MAX_SIDE:
        ds *= 2
    return float(ds)


# where the run seed goes: every random choice of the method's pipeline (gaussian
# initialisation and densification, pixel/mask sampling of feature training, the clustering
# sample). The 2D masks are the benchmark's input and keep their own seed (masks.seed).
SEED_PATHS = (("geometry", "train", "seed"), ("method", "features", "seed"), ("method", "clustering", "seed"))


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
        node = cfg
        for p in path[:-1]:
            node = node.get(p) if isinstance(node, dict) else None
        if isinstance(node, dict) and path[-1] in node:
            node[path[-1]] = seed
    return cfg


def without_seed(overrides: dict) -> dict:
    return {k: v for k, v in overrides.items() if k != "seed"}


# the geometry's settings under each CPU preset (trase.reconstruction_config)
CPU_GEOMETRY = {"cpu": "cpu", "cpu-v4": "cpu_v4", "cpu-v3": "cpu_v3", "cpu-v2": "cpu_v2", "cpu-v1": "cpu_v1"}
RIG_PRESETS = ("cpu", "cpu-v4", "cpu-v3")  # CPU presets whose settings depend on the rig (monocular or not)
PRESETS = ("paper", *CPU_GEOMETRY)  # geometry presets; "auto": paper with a GPU, cpu without
# the method's preset under each geometry preset (cpu-v4 to cpu-v1: older CPU geometry, today's CPU features)
METHOD_PRESET = {"paper": "paper", **{p: "cpu" for p in CPU_GEOMETRY}}


def resolve_preset(overrides: dict) -> str:
    """The run's one preset, from ``--set geometry.preset`` (default auto): it decides the
    geometry's schedule and the method's settings alike."""
    preset = overrides.get("geometry", {}).get("preset", "auto")
    if preset == "auto":
        import torch

        preset = "paper" if torch.cuda.is_available() else "cpu"
    if preset not in PRESETS:
        raise ConfigError(f"--set geometry.preset={preset}: choose auto, {', '.join(PRESETS)}")
    return preset


def default_config(method, spec, variant: str, overrides: dict,
                   image_size: tuple[int, int] | None = None) -> dict:
    """Full config of one benchmark run: defaults for the dataset and variant under the one
    preset (``resolve_preset``), the run seed (``--set seed=S``, written into every seeded
    section), then ``overrides`` (an explicit ``method.features.seed`` still wins;
    ``method.preset`` follows the geometry's). ``image_size`` (W, H) of the benchmark images
    picks the cpu preset's training resolution."""
    base = _sections(method, overrides, spec.key, spec.monocular,
                     {"warm_up": spec.warm_up, "densify_until": spec.densify_until}, image_size,
                     "synthetic" if variant == "synthetic" else "classical")
    # clicks on every object of interest, in the first test frame it appears in
    # (benchmark.protocol.prompts; "gt-first-frame": the first non-empty frame only)
    base["prompts"] = {"rule": "gt-first-appearance",
                       # click sets scored beside the run's own (benchmark.protocol.prompts): 1 = the
                       # single-click protocol alone
                       "click_sets": 5}
    return _resolve(method, base, overrides)


def capture_config(method, monocular: bool, capture: dict, overrides: dict,
                   image_size: tuple[int, int] | None = None) -> dict:
    """Full config of ``trase-bench fit`` on a capture of one's own: as a run's, with the
    method's settings for the capture's rig, Deformable-3DGS's default schedule under the
    paper preset, masks by the classical generator (or SAM with --set masks.generator=sam
    masks.checkpoint=PATH, or masks made elsewhere with masks.generator=files masks.dir=PATH), and the ``capture`` section (benchmark.captures.CaptureOptions)."""
    base = _sections(method, overrides, None, monocular, {}, image_size, "classical")
    base["masks"]["dir"] = None  # generator "files": masks made elsewhere (benchmark.pipeline.masks)
    base["capture"] = dict(capture)
    return _resolve(method, base, overrides)


def _sections(method, overrides: dict, dataset: str | None, monocular: bool, schedule: dict,
              image_size: tuple[int, int] | None, mask_generator: str) -> dict:
    from trase.reconstruction_config import ReconstructionConfig

    preset = resolve_preset(overrides)
    method_preset = METHOD_PRESET[preset]
    asked = overrides.get("method", {}).get("preset") if isinstance(overrides.get("method"), dict) else None
    if asked is not None and asked != method_preset:
        raise ConfigError(f"--set method.preset={asked}: the method's preset follows the run's "
                          f"(geometry.preset={preset} gives {method_preset}); set --set geometry.preset instead")
    if preset == "paper":
        train = ReconstructionConfig.paper(**schedule)
    else:
        # a few CPU minutes (ReconstructionConfig.cpu; cpu-v4 to cpu-v1: the earlier CPU
        # presets, kept for comparisons). Training resolution: see cpu_train_downscale.
        make = getattr(ReconstructionConfig, CPU_GEOMETRY[preset])
        rig = {"monocular": monocular} if preset in RIG_PRESETS else {}
        train = make(image_downscale=cpu_train_downscale(image_size), **rig)
    return {
        "masks": {
            "generator": mask_generator,
            "checkpoint": None,  # SAM checkpoint path (generator "sam")
            "seed": 0,
        },
        "geometry": {
            "source": "reconstruct",  # reconstruct | ground-truth (synthetic) | import
            "preset": preset,
            "model_dir": None,  # for source=import: a Deformable-3DGS/TRASE model directory
            "train": train.to_dict(),
        },
        "method": method.default_config(dataset, method_preset, monocular),
    }


def _resolve(method, base: dict, overrides: dict) -> dict:
    from trase.reconstruction_config import ReconstructionConfig

    cfg = merge(apply_seed(base, run_seed(overrides)), overrides)
    # typed once, here: a wrong value stops the run before any stage, naming the setting
    typed(ReconstructionConfig, cfg["geometry"]["train"], "geometry.train")
    _resolve_device(cfg["geometry"]["train"], "geometry.train.device")
    if isinstance(cfg["method"].get("features"), dict):
        _resolve_device(cfg["method"]["features"], "method.features.device")
    method.check_config(cfg["method"])
    return cfg


def _resolve_device(section: dict, name: str) -> None:
    """``section["device"]`` "auto" -> "cuda" or "cpu", written into the config (so a run's
    record and cache keys say where it computed). CUDA rasterizes with gsplat: without it the
    run stops here, before any stage, rather than at its first render."""
    from trase.devices import DeviceError, gsplat_missing, resolve_device

    try:
        section["device"] = resolve_device(section.get("device", "auto")).type
    except DeviceError as exc:
        raise ConfigError(f"--set {name}: {exc}") from None
    why = gsplat_missing(section["device"])
    if why:
        raise ConfigError(f"{name}: {why}; or --set {name}=cpu")
