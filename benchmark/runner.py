"""``trase-bench run``: masks -> geometry -> method fit -> prompts -> evaluation, per sequence.

Every stage goes through the stage cache (benchmark.cache): its key hashes its own config
section and its inputs' keys, so a rerun, or another method on the same scene, reuses the
masks and the reconstruction and says so. Results land in the run's directory,
``<out>/<method>/<dataset>/<sequence>/<name>/results.json`` (``benchmark.runs``: name = --name or
c<config hash>), with predictions beside them.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmark.cache import StageCache, StageRecord, config_hash
from benchmark.config import ConfigError, merge, parse_overrides
from benchmark.errors import UserError
from benchmark.io import atomic_directory, sha256_files
from benchmark.results import write_results
from benchmark.runs import check_free, run_dir, run_info, run_name
from benchmark.scoring import read_mask, score_masks

STAGES = ("masks", "geometry", "fit", "prompts", "evaluate")


@dataclasses.dataclass
class RunOptions:
    method: str
    dataset: str
    sequences: list[str] | None = None  # None: every sequence (synthetic default if no data)
    data_root: Path | None = None
    out_dir: Path = Path("runs")
    cache_dir: Path | None = None  # default <out>/.cache
    overrides: list[str] = dataclasses.field(default_factory=list)  # --set key=value
    jobs: int = 1
    progress: bool = True
    name: str | None = None  # run directory name; None: c<config hash> (benchmark.runs)
    study: str | None = None  # set by ablation studies: the run is a variant of this study
    study_variant: str | None = None
    seeds: list[int] | None = None  # run seeds (each its own run, --set seed=S); None: as --set says
    keep_existing: bool = False  # a run whose directory holds results of this config is not redone

    def per_seed(self) -> list[RunOptions]:
        """One options object per run seed (just this one without ``seeds``)."""
        if not self.seeds:
            return [self]
        if any(o.strip().startswith("seed=") for o in self.overrides):
            raise ConfigError("give the run seed either with --seeds or with --set seed=S, not both")
        return [dataclasses.replace(self, seeds=None, overrides=[*self.overrides, f"seed={s}"])
                for s in self.seeds]

    @property
    def cache_root(self) -> Path:
        return Path(self.cache_dir) if self.cache_dir else Path(self.out_dir) / ".cache"


class Reporter:
    """One line per stage on stderr: what ran, what was reused, how long; plus an ETA."""

    def __init__(self, enabled: bool, n_sequences: int):
        self.enabled = enabled
        self.n_sequences = n_sequences
        self.t0 = time.perf_counter()
        self.done_sequences = 0

    def stage(self, seq: str, rec: StageRecord) -> None:
        if not self.enabled:
            return
        what = "reused (cached)" if rec.skipped else f"done in {rec.seconds:.1f}s"
        print(f"  [{seq}] {rec.stage:<9} {what}  peak {rec.peak_rss_mb:.0f} MiB  key {rec.key}",
              file=sys.stderr, flush=True)

    def start(self, seq: str, index: int) -> None:
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.t0
        eta = ""
        if self.done_sequences:
            left = (self.n_sequences - self.done_sequences) * elapsed / self.done_sequences
            eta = f", ETA {left / 60:.1f} min"
        print(f"sequence {index + 1}/{self.n_sequences}: {seq}{eta}", file=sys.stderr, flush=True)

    def finish(self) -> None:
        self.done_sequences += 1


# -- configuration ---------------------------------------------------------------------------
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


def default_config(method, spec, variant: str, overrides: dict,
                   image_size: tuple[int, int] | None = None) -> dict:
    """Full config of one run: defaults for the dataset and variant, the run seed (``--set
    seed=S``, written into every seeded section), then ``overrides`` (an explicit
    ``method.features.seed`` still wins). ``image_size`` (W, H) of the benchmark images picks
    the cpu preset's training resolution."""
    import torch

    from trase.reconstruct import ReconstructionConfig

    geo_over = overrides.get("geometry", {})
    preset = geo_over.get("preset", "auto")
    if preset == "auto":
        preset = "paper" if torch.cuda.is_available() else "cpu"
    if preset not in ("paper", "cpu", "cpu-v1"):
        raise ConfigError(f"--set geometry.preset={preset}: choose auto, paper, cpu or cpu-v1")
    sched = {"warm_up": spec.warm_up, "densify_until": spec.densify_until}
    if preset == "paper":
        train = ReconstructionConfig.paper(**sched)
    else:
        # a few CPU minutes (ReconstructionConfig.cpu; cpu-v1: the first CPU preset, kept for
        # comparisons). Training resolution: see cpu_train_downscale.
        make = ReconstructionConfig.cpu if preset == "cpu" else ReconstructionConfig.cpu_v1
        train = make(image_downscale=cpu_train_downscale(image_size))
    base = {
        "masks": {
            "generator": "synthetic" if variant == "synthetic" else "classical",
            "checkpoint": None,  # SAM checkpoint path (generator "sam")
            "seed": 0,
        },
        "geometry": {
            "source": "reconstruct",  # reconstruct | ground-truth (synthetic) | import
            "preset": preset,
            "model_dir": None,  # for source=import: a Deformable-3DGS/TRASE model directory
            "train": train.to_dict(),
        },
        "method": method.default_config(spec),
        # clicks on every object of interest, in the first test frame it appears in
        # (trase.prompts; "gt-first-frame": the first non-empty frame only)
        "prompts": {"rule": "gt-first-appearance",
                    # click sets scored beside the run's own (trase.prompts): 1 = the single-click
                    # protocol alone
                    "click_sets": 5},
    }
    return merge(apply_seed(base, run_seed(overrides)), overrides)


def scene_fingerprint(scene) -> str:
    """Key of the input data: cameras, times and each image's name, size and mtime."""
    h = hashlib.sha256()
    for v in scene.train + scene.test:
        st = os.stat(v.image_path)
        h.update(json.dumps([v.name, v.camera.to_dict(), str(v.image_path), st.st_size,
                             st.st_mtime_ns], sort_keys=True).encode())
    h.update(np.ascontiguousarray(scene.points, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


# -- stages ----------------------------------------------------------------------------------
def stage_masks(cache: StageCache, scene, cfg: dict, scene_key: str, progress: bool) -> StageRecord:
    import masks as masklib

    mcfg = cfg["masks"]
    key = cache.key("masks", mcfg, {"scene": scene_key})

    def work(d: Path) -> dict:
        instance_maps = None
        if mcfg["generator"] == "synthetic":
            instance_maps = synthetic_truth(scene).instance_maps
        gen = make_mask_generator(mcfg)
        paths = masklib.generate_scene_masks(scene.train, gen, d, progress=progress,
                                             instance_maps=instance_maps)
        sizes = [p.stat().st_size for p in paths]
        return {"n_views": len(paths), "bytes_per_view": int(np.mean(sizes)) if sizes else 0}

    return cache.run("masks", key, work, mcfg)


def make_mask_generator(mcfg: dict):
    from masks.generators.base import make_generator

    g = mcfg["generator"]
    if g == "sam":
        if not mcfg.get("checkpoint"):
            raise ConfigError("masks.generator=sam needs --set masks.checkpoint=PATH (a SAM .pth file)")
        return make_generator("sam", checkpoint=mcfg["checkpoint"])
    if g == "synthetic":
        return make_generator("synthetic", seed=mcfg["seed"])
    return make_generator(g)


def synthetic_truth(scene):
    """The scene's truth (benchmark.datasets.truth); a clear error on real data."""
    if scene.truth is None:
        raise ConfigError(f"{scene.root}: not a synthetic scene (no synthetic/manifest.json)")
    return scene.truth


def stage_geometry(cache: StageCache, scene, cfg: dict, scene_key: str, progress: bool) -> StageRecord:
    gcfg = cfg["geometry"]
    key = cache.key("geometry", gcfg, {"scene": scene_key})

    def work(d: Path) -> dict:
        from trase.reconstruct import ReconstructionConfig, evaluate_psnr, reconstruct

        src = gcfg["source"]
        if src == "ground-truth":
            shutil.copyfile(synthetic_truth(scene).geometry_path, d / "geometry.npz")
        elif src == "import":
            if not gcfg.get("model_dir"):
                raise ConfigError("geometry.source=import needs --set geometry.model_dir=PATH")
            shutil.copytree(gcfg["model_dir"], d / "model", dirs_exist_ok=True)
        elif src == "reconstruct":
            try:
                rcfg = ReconstructionConfig(**gcfg["train"])
            except TypeError as exc:
                raise ConfigError(f"geometry.train: {exc}") from None
            reconstruct(scene.train, scene.points, scene.point_colors, rcfg, d / "model",
                        resume=True, progress=progress)
        else:
            raise ConfigError(f"--set geometry.source={src}: choose reconstruct, ground-truth or import")
        gaussians, deformation = load_geometry(d)
        psnr = evaluate_psnr(gaussians, deformation, scene.test) if scene.test else None
        return {"source": src, "n_gaussians": int(gaussians.num_gaussians),
                "test_psnr": None if psnr is None else round(float(psnr), 3)}

    return cache.run("geometry", key, work, gcfg)


def load_geometry(stage_dir: Path):
    """(gaussians, deformation) from a geometry stage directory."""
    from trase.checkpoint import load_model, load_tabulated_geometry

    if (stage_dir / "geometry.npz").exists():
        g, deform, _ = load_tabulated_geometry(stage_dir / "geometry.npz")
        return g, deform
    return load_model(stage_dir / "model")


def stage_features(cache: StageCache, method, scene, cfg: dict, masks_rec: StageRecord,
                   geo_rec: StageRecord, geometry: Callable, progress: bool) -> StageRecord:
    """Learned per-gaussian features: keyed only on the settings that change them."""
    fcfg = {"method": method.name, **{k: cfg["method"][k] for k in method.FEATURE_KEYS if k in cfg["method"]}}
    key = cache.key("features", fcfg, {"masks": masks_rec.key, "geometry": geo_rec.key})

    def work(d: Path) -> dict:
        gaussians, deformation = geometry()
        feats, info = method.learn(scene, gaussians, deformation, masks_rec.path, cfg["method"], d / "work",
                                   progress=progress)
        np.save(d / "features.npy", feats)
        shutil.rmtree(d / "work", ignore_errors=True)  # pixel-weight cache, not a result
        return _jsonable(info)

    return cache.run("features", key, work, fcfg)


def stage_fit(cache: StageCache, method, scene, cfg: dict, masks_rec: StageRecord,
              geo_rec: StageRecord, geometry: Callable, progress: bool
              ) -> tuple[StageRecord | None, StageRecord]:
    """(features record or None, fit record). Methods with ``learn``/``group`` halves get two
    cached stages, so clustering and filtering changes reuse the trained features.
    ``geometry()`` returns the (gaussians, deformation) of ``geo_rec``, loaded once."""
    mcfg = {"method": method.name, **cfg["method"]}
    if hasattr(method, "learn") and hasattr(method, "group"):
        feat_rec = stage_features(cache, method, scene, cfg, masks_rec, geo_rec, geometry, progress)
        key = cache.key("fit", mcfg, {"features": feat_rec.key, "geometry": geo_rec.key})

        def work(d: Path) -> dict:
            gaussians, deformation = geometry()
            feats = np.load(feat_rec.path / "features.npy")
            fitted = method.group(feats, cfg["method"], gaussians, deformation, feat_rec.info)
            fitted.save(d)
            return {"timings": fitted.timings, "stats": _jsonable(fitted.stats)}

        return feat_rec, cache.run("fit", key, work, mcfg)

    key = cache.key("fit", mcfg, {"masks": masks_rec.key, "geometry": geo_rec.key})

    def work_whole(d: Path) -> dict:
        gaussians, deformation = geometry()
        fitted = method.fit(scene, gaussians, deformation, masks_rec.path, cfg["method"], d / "work",
                            progress=progress)
        fitted.save(d)
        shutil.rmtree(d / "work", ignore_errors=True)
        return {"timings": fitted.timings, "stats": _jsonable(fitted.stats)}

    return None, cache.run("fit", key, work_whole, mcfg)


def stage_prompts(cache: StageCache, scene, cfg: dict, gt_key: str) -> StageRecord:
    from trase.prompts import BENCHMARK_RULES, load_or_make_prompts

    pcfg = cfg["prompts"]
    if pcfg["rule"] not in BENCHMARK_RULES:
        raise ConfigError(f"--set prompts.rule={pcfg['rule']}: choose {' or '.join(BENCHMARK_RULES)}")
    n_sets = pcfg.get("click_sets", 1)
    if isinstance(n_sets, bool) or not isinstance(n_sets, int) or n_sets < 1:
        raise ConfigError(f"--set prompts.click_sets={n_sets!r}: a whole number >= 1 (1: the run's own clicks only)")
    key = cache.key("prompts", pcfg, {"gt": gt_key})

    def work(d: Path) -> dict:
        bp = load_or_make_prompts(d / "prompts.json", scene.test, lambda i: read_mask(scene.gt_masks[i]),
                                  rule=pcfg["rule"], click_sets=n_sets)
        return {"view": bp.view, "n_clicks": len(bp.clicks), "frames": bp.frames(),
                "click_sets": 1 + len(bp.alternatives)}

    return cache.run("prompts", key, work, pcfg)


def _jsonable(obj):
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def cluster_colours(labels: np.ndarray, seed: int = 0) -> np.ndarray:
    """[N] cluster ids -> [N, 3] RGB in [0, 1], a fixed random colour per cluster."""
    rng = np.random.default_rng(seed)
    palette = rng.uniform(0.15, 1.0, size=(int(labels.max()) + 2 if labels.size else 1, 3))
    return palette[np.asarray(labels, np.int64)]


def render_clusters(fitted, camera) -> np.ndarray:
    """Test view rendered with one colour per cluster -> uint8 [H, W, 3]."""
    import torch

    from trase.deformation import deformed
    from trase.render import rasterize

    g = fitted.gaussians
    with torch.no_grad():
        means, quats, scales = deformed(g, fitted.deformation, camera.time)
        colours = torch.as_tensor(cluster_colours(fitted.labels), dtype=means.dtype)
        out = rasterize(means, quats, scales, g.opacities.detach(), camera, colors=colours)
    return (out.color.clamp(0, 1).numpy() * 255).astype(np.uint8)


def score_click_sets(method, fitted, scene, prompts, gts: list[np.ndarray], names: list[str],
                     first: dict, first_preds: list[np.ndarray]) -> dict | None:
    """Official mIoU of every click set (trase.prompts) -> per set (its clicks, the cluster
    each chose, the clusters chosen, mIoU) and median / worst / best; None with a single set.
    Set 0 is the run's own clicks: ``first`` (its entry, already scored) and ``first_preds``;
    a set choosing clusters already rendered reuses their masks."""
    sets = prompts.click_sets()
    if len(sets) < 2:
        return None
    rendered = {tuple(first.get("selected", ())): first_preds}
    out = [first]
    for j, p in enumerate(sets[1:], start=1):
        entry: dict = {"set": j, "clicks": _click_list(p)}
        if getattr(method, "selects_clusters", False) and fitted.gaussians is not None:
            per_click = method.click_clusters(fitted, scene, p)
            chosen = tuple(sorted({k for k in per_click if k >= 0}))
            if chosen not in rendered:
                rendered[chosen] = method.render_selection(fitted, scene, list(chosen))
            preds = rendered[chosen]
            entry |= {"click_clusters": per_click, "selected": list(chosen)}
        else:
            preds = method.segment(fitted, scene, p)
        entry["miou"] = score_masks(dict(zip(names, preds)), dict(zip(names, gts)), "official").miou
        out.append(entry)
    scores = np.array([e["miou"] for e in out], dtype=float)
    return {"n": len(out), "median": float(np.median(scores)), "worst": float(scores.min()),
            "best": float(scores.max()), "sets": out,
            "note": "official mIoU per click set; set 0 gives the run's score"}


def _click_list(prompts) -> list[list[float]]:
    return [[c.view_index, round(c.u, 1), round(c.v, 1)] for c in prompts.clicks]


def evaluate(method, fitted, scene, prompts, directory: Path) -> dict:
    """Predicted masks for every test view -> pred/*.png, scores (v1 and official), oracle,
    scores of the other click sets."""
    import cv2

    preds = method.segment(fitted, scene, prompts)
    if len(preds) != len(scene.test):
        raise RuntimeError(f"{method.name}.segment returned {len(preds)} masks for {len(scene.test)} test views")
    selected = list(fitted.stats.get("selected_clusters", []))
    gts = [read_mask(p) for p in scene.gt_masks]
    names = [f"{i:05d}" for i in range(len(scene.test))]
    with atomic_directory(directory / "pred") as d:
        for n, m in zip(names, preds):
            cv2.imwrite(str(d / f"{n}.png"), m.astype(np.uint8) * 255)
    shown = names[:: max(1, len(names) // 8)][:8]
    with atomic_directory(directory / "clusters") as d:
        for n in shown:
            rgb = render_clusters(fitted, scene.test[names.index(n)].camera)
            cv2.imwrite(str(d / f"{n}.png"), rgb[..., ::-1])
        if fitted.gaussians is not None:  # for agreement between seeds (benchmark.stability)
            from benchmark.stability import save_cluster_maps

            save_cluster_maps(d, fitted, {n: scene.test[names.index(n)].camera for n in shown})
    official = score_masks(dict(zip(names, preds)), dict(zip(names, gts)), "official")
    per_click = fitted.stats.get("click_clusters")  # methods that choose clusters by clicks
    first = {"set": 0, "clicks": _click_list(prompts), "miou": official.miou}
    if per_click is not None:
        first |= {"click_clusters": list(per_click), "selected": selected}
    out = {
        "v1": score_masks(dict(zip(names, preds)), dict(zip(names, gts)), "v1"),
        "official": official,
        "selected": selected,
        "click_clusters": per_click,
        "click_sets": score_click_sets(method, fitted, scene, prompts, gts, names, first, preds),
    }
    if hasattr(method, "segment_oracle"):
        opreds, oclusters = method.segment_oracle(fitted, scene, gts)
        out["oracle"] = score_masks(dict(zip(names, opreds)), dict(zip(names, gts)), "v1")
        out["oracle_clusters"] = [int(c) for c in oclusters]
    return out


def stage_ceiling(cache: StageCache, scene, fitted, geo_key: str, gt_key: str) -> dict | None:
    """The geometry's label ceiling (benchmark.ceiling) on synthetic scenes, cached under the
    geometry, the ground truth and the rendering rule: every method and ablation variant run on
    one geometry reuses it. None on real data."""
    if scene.truth is None or fitted.gaussians is None:
        return None
    ccfg = {"rule": str(fitted.config.get("render_rule", "alone")),
            "threshold": float(fitted.config.get("alpha_threshold", 0.5))}
    key = cache.key("ceiling", ccfg, {"geometry": geo_key, "gt": gt_key})

    def work(d: Path) -> dict:
        from benchmark.ceiling import label_ceiling

        gts = [read_mask(p) for p in scene.gt_masks]
        score, info = label_ceiling(fitted.gaussians, fitted.deformation, scene, gts, ccfg["rule"],
                                    ccfg["threshold"])
        return {k: score.to_dict()[k] for k in ("miou", "macc", "pooled_iou")} | info

    return cache.run("ceiling", key, work, ccfg).info


# -- one sequence ----------------------------------------------------------------------------
def run_sequence(opts: RunOptions, sequence: str | None, reporter: Reporter, index: int) -> Path:
    from benchmark.datasets import get_dataset, load_scene
    from benchmark.datasets.synthetic import find_or_generate
    from benchmark.methods import get_method

    spec = get_dataset(opts.dataset)
    scene_dir, variant = find_or_generate(spec.key, sequence, opts.data_root)
    scene = load_scene(spec.key, scene_dir)
    seq = scene.sequence
    reporter.start(seq, index)
    if not scene.gt_masks:
        raise UserError(f"{scene_dir}: no ground-truth masks for {spec.key}/{seq}; cannot evaluate "
                        f"(expected gt_masks/ in the scene or {spec.display_name}/{seq}/gt_masks under the data root)")
    method = get_method(opts.method)
    overrides = parse_overrides(opts.overrides)
    views = scene.test or scene.train
    size = (views[0].camera.width, views[0].camera.height) if views else None
    cfg = default_config(method, spec, variant, overrides, size)
    chash = config_hash(cfg)
    # runs that differ only in their seed share this hash: one row of a table, over seeds
    group = config_hash(default_config(method, spec, variant, without_seed(overrides), size))
    is_default = group == config_hash(default_config(method, spec, variant, {}, size))
    name = run_name(group, opts.name, with_hash=bool(opts.study), seed=cfg["seed"])
    out_dir = run_dir(opts.out_dir, opts.method, spec.key, seq, name)
    check_free(out_dir, chash)  # before any work: a run with another config is never overwritten
    if opts.keep_existing and (out_dir / "results.json").is_file():
        if opts.progress:
            print(f"  [{seq}] kept: {out_dir} holds this config's results", file=sys.stderr, flush=True)
        reporter.finish()
        return out_dir / "results.json"
    cache = StageCache(opts.cache_root)
    scene_key = scene_fingerprint(scene)
    gt_key = sha256_files(list(scene.gt_masks))[:16]

    recs = {}
    recs["masks"] = stage_masks(cache, scene, cfg, scene_key, opts.progress)
    reporter.stage(seq, recs["masks"])
    recs["geometry"] = stage_geometry(cache, scene, cfg, scene_key, opts.progress)
    reporter.stage(seq, recs["geometry"])
    # loaded at most once per sequence, and only by a stage that has to run
    geometry = functools.cache(lambda: load_geometry(recs["geometry"].path))
    feat_rec, recs["fit"] = stage_fit(cache, method, scene, cfg, recs["masks"], recs["geometry"], geometry,
                                      opts.progress)
    if feat_rec is not None:
        recs["features"] = feat_rec
        reporter.stage(seq, feat_rec)
    reporter.stage(seq, recs["fit"])
    recs["prompts"] = stage_prompts(cache, scene, cfg, gt_key)
    reporter.stage(seq, recs["prompts"])

    from benchmark.cache import PeakMemory
    from benchmark.methods import FittedModel
    from benchmark.stability import geometry_checksum
    from trase.checkpoint import model_storage
    from trase.prompts import BenchmarkPrompts

    out_dir.mkdir(parents=True, exist_ok=True)
    with PeakMemory() as mem:
        t0 = time.perf_counter()
        gaussians, deformation = geometry()
        fitted = FittedModel.load(recs["fit"].path, gaussians, deformation)
        prompts_path = recs["prompts"].path / "prompts.json"
        from benchmark.io import read_json

        prompts_dict = read_json(prompts_path, "prompts file")
        prompts = BenchmarkPrompts.from_dict(prompts_dict, str(prompts_path))
        ev = evaluate(method, fitted, scene, prompts, out_dir)
        ceiling = stage_ceiling(cache, scene, fitted, recs["geometry"].key, gt_key)
        seconds = time.perf_counter() - t0
    recs["evaluate"] = StageRecord("evaluate", "-", out_dir, False, seconds, mem.peak_mb, {})
    reporter.stage(seq, recs["evaluate"])

    v1, official = ev["v1"].to_dict(), ev["official"].to_dict()
    pred_files = sorted((out_dir / "pred").glob("*.png"))
    record = {
        "run": run_info(name, opts.overrides, is_default, opts.study, opts.study_variant, seed=cfg["seed"],
                        group=group),
        "method": opts.method,
        "dataset": spec.key,
        "sequence": seq,
        "variant": variant,
        # which synthetic scene (standard and hard results must never be mixed); None: real data
        "synthetic_scene": dict(scene.truth.info) if scene.truth else None,
        "metrics": {**{k: v1[k] for k in ("miou", "macc", "pooled_iou", "metric", "metric_version",
                                          "n_frames", "both_empty", "missing")},
                    "official": {k: official[k] for k in ("miou", "macc", "pooled_iou", "metric_version")}},
        "per_frame": v1["per_frame"],
        "oracle": ({k: ev["oracle"].to_dict()[k] for k in ("miou", "macc", "pooled_iou")}
                   | {"clusters": ev["oracle_clusters"],
                      "note": "upper bound: clusters chosen with the ground truth; not the method's score"})
        if "oracle" in ev else None,
        "ceiling": (ceiling
                    | {"note": "geometry's ceiling: every gaussian labelled by the object it shows most in "
                               "the training views' instance maps (synthetic scenes only); an estimate, not a strict "
                               "bound; not the method's score"})
        if ceiling else None,
        "stages": {name: r.to_dict() for name, r in recs.items()},
        "n_gaussians": int(fitted.features.shape[0]),
        "n_clusters": int(fitted.stats.get("n_clusters", 0)),
        "selected_clusters": ev["selected"],
        "click_clusters": ev["click_clusters"],  # per click of the prompts, in order
        "click_sets": ev["click_sets"],
        "feature_space": fitted.stats.get("feature_space"),
        # the model itself (gaussians + features + deformation, float32), as the paper's storage
        "geometry_checksum": geometry_checksum(fitted.gaussians) if fitted.gaussians is not None else None,
        "storage": model_storage(fitted.gaussians, fitted.deformation, int(fitted.features.shape[1]))
        if fitted.gaussians is not None else None,
        "config": cfg,
        "config_hash": chash,
        "seeds": {"run": cfg["seed"], "masks": cfg["masks"]["seed"], "geometry": cfg["geometry"]["train"].get("seed"),
                  "features": cfg["method"].get("features", {}).get("seed"),
                  "clustering": cfg["method"].get("clustering", {}).get("seed")},
        "checksums": {"gt": gt_key, "pred": sha256_files(pred_files)[:16]},
        "prompts": prompts_dict,
        "scene_dir": str(scene_dir),
        "frames": [{"frame": f"{i:05d}", "view": v.name, "image": str(v.image_path),
                    "gt": str(scene.gt_masks[i]), "pred": f"pred/{i:05d}.png"}
                   for i, v in enumerate(scene.test)],
    }
    path = out_dir / "results.json"
    write_results(path, _jsonable(record))
    reporter.finish()
    return path


def run(opts: RunOptions) -> list[Path]:
    """Run one method on the requested sequences (for each run seed); returns the
    results.json paths."""
    from benchmark.datasets import get_dataset

    if opts.seeds:
        return [p for one in opts.per_seed() for p in run(one)]
    spec = get_dataset(opts.dataset)
    sequences = opts.sequences or default_sequences(spec, opts.data_root)
    reporter = Reporter(opts.progress, len(sequences))
    if opts.jobs > 1 and len(sequences) > 1:
        from concurrent.futures import ProcessPoolExecutor

        opts_one = dataclasses.replace(opts, jobs=1)
        with ProcessPoolExecutor(max_workers=opts.jobs) as ex:
            futs = [ex.submit(run_sequence, opts_one, s, Reporter(opts.progress, len(sequences)), i)
                    for i, s in enumerate(sequences)]
            return [f.result() for f in futs]
    return [run_sequence(opts, s, reporter, i) for i, s in enumerate(sequences)]


def default_sequences(spec, data_root: Path | None) -> list[str | None]:
    """The paper's sequences present under the data root; if none, the synthetic default."""
    from benchmark.datasets import find_scene_dir

    root = data_root or (Path(os.environ["TRASE_DATA"]) if os.environ.get("TRASE_DATA") else None)
    found = [s for s in spec.sequences if root and find_scene_dir(spec.key, s, root)]
    return found or [None]
