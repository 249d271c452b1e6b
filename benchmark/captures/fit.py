"""``trase-bench fit``: the method on a capture of one's own, no ground truth needed.

The benchmark's stages without its protocol: masks (the classical generator, or SAM with a
local checkpoint), geometry (reconstruction under the run's preset), features and clusters,
through the same stage cache; then the fitted scene is exported into one folder::

    <out>/fit.json          what was fitted: capture, notices, config, stage keys and times,
                            held-out PSNR (--holdout), counts. Written last: its presence
                            means the folder is complete. Never a benchmark result.
    <out>/views.json        every view's camera (train and held out), for select/render
    <out>/model/            the geometry in the Deformable-3DGS/TRASE layout (trase.checkpoint)
    <out>/segmentation/     features.npy, clusters.npy, keep.npy, point_cloud.ply, fitted.json
    <out>/previews/         cluster colours at a few training views (where to click)
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
from pathlib import Path

import numpy as np

from benchmark.cache import StageCache, config_hash
from benchmark.config import merge, parse_overrides, typed
from benchmark.io import atomic_directory, atomic_write_bytes, atomic_write_json
from benchmark.numerics import check as check_numerics
from benchmark.pipeline import fit, geometry, masks, tracks
from benchmark.pipeline.context import SequenceRun, render_near, scene_fingerprint
from benchmark.pipeline.settings import capture_settings

FIT_STAGES = (masks.run, geometry.run, tracks.run, fit.run)
FIT_FILE, VIEWS_FILE = "fit.json", "views.json"
N_PREVIEWS = 4


@dataclasses.dataclass
class FitOptions:
    scene_dir: Path
    out_dir: Path | None = None  # default fits/<scene folder name>
    method: str = "trase"
    format: str = "auto"  # capture layout (benchmark.captures.FORMATS) or auto
    holdout: str = "none"  # none | every:N | layout
    overrides: list[str] = dataclasses.field(default_factory=list)  # --set key=value
    cache_dir: Path | None = None  # default <out>/.cache
    progress: bool = True


def monocular(scene) -> bool:
    """One view per time (a single moving camera) rather than a rig filming each time."""
    times = [round(v.time, 9) for v in scene.train + scene.test]
    return max(np.unique(times, return_counts=True)[1]) == 1 if times else True


def fit_capture(opts: FitOptions) -> Path:
    """Fit the method to the capture in ``opts.scene_dir``; returns ``<out>/fit.json``."""
    from benchmark.captures import CaptureOptions, load_capture
    from benchmark.methods import get_method

    overrides = parse_overrides(opts.overrides)
    capture = merge(CaptureOptions(format=opts.format, holdout=opts.holdout).to_dict(),
                    overrides.get("capture", {}), "capture.")
    scene = load_capture(opts.scene_dir, typed(CaptureOptions, capture, "capture"))
    say = _say(opts.progress)
    say(f"capture {opts.scene_dir} ({scene.extras['format']}): {len(scene.train)} training views"
        + (f", {len(scene.test)} held out" if scene.test else "") + f", {len(scene.points)} initial points")
    for note in scene.extras["notices"]:
        say(f"  note: {note}")
    method = get_method(opts.method)
    first = scene.train[0].camera
    settings = capture_settings(method, monocular(scene), capture, overrides, (first.width, first.height))
    scene = scene.with_near(render_near(settings.geometry.source, settings.geometry.train.near_plane))
    out = Path(opts.out_dir) if opts.out_dir else Path("fits") / scene.sequence
    check_numerics(settings.machine.numerics)
    cache = StageCache(Path(opts.cache_dir) if opts.cache_dir else out / ".cache", numerics=settings.machine.numerics)
    ctx = SequenceRun(cache, scene, settings, method, opts.progress, scene_fingerprint(scene), gt_key="")
    for stage in FIT_STAGES:
        for rec in stage(ctx):
            ctx.records[rec.stage] = rec
            say(f"  {rec.stage:<9} {'reused (cached)' if rec.skipped else f'done in {rec.seconds:.1f}s'}  key {rec.key}")
    return export(ctx, out, opts)


def export(ctx: SequenceRun, out: Path, opts: FitOptions) -> Path:
    """The fitted scene into ``out`` (module docstring); fit.json last."""
    from benchmark.methods import FittedModel
    from benchmark.pipeline.evaluate import render_clusters
    from imagefiles import png_bytes, read_rgb8

    out.mkdir(parents=True, exist_ok=True)
    (out / FIT_FILE).unlink(missing_ok=True)  # the folder is incomplete until fit.json is back
    geo_rec, fit_rec = ctx.records["geometry"], ctx.records["fit"]
    with atomic_directory(out / "model") as d:
        shutil.copytree(geo_rec.path / "model", d, dirs_exist_ok=True)
    with atomic_directory(out / "segmentation") as d:
        for f in fit_rec.path.iterdir():
            if f.is_file():
                shutil.copy2(f, d / f.name)
    gaussians, deformation = ctx.geometry
    fitted = FittedModel.load(out / "segmentation", gaussians, deformation, ctx.method.settings_class())
    scene = ctx.scene
    shown = [scene.train[i] for i in np.unique(np.linspace(0, len(scene.train) - 1, N_PREVIEWS).round().astype(int))]
    with atomic_directory(out / "previews") as d:
        for v in shown:
            pair = np.concatenate([read_rgb8(v.image_path), render_clusters(fitted, v.camera)], axis=1)
            atomic_write_bytes(d / f"{_file_name(v.name)}.png", png_bytes(pair))
    atomic_write_json(out / VIEWS_FILE, {split: [{"name": v.name, "image": str(v.image_path), "frame": int(v.frame),
                                                   "camera": v.camera.to_dict()} for v in views]
                                         for split, views in (("train", scene.train), ("test", scene.test),
                                                              ("validation", scene.validation))})
    record = {
        "kind": "capture-fit",  # not a benchmark result: no ground truth, never in a leaderboard
        "scene_dir": str(Path(opts.scene_dir).resolve()),
        "format": scene.extras["format"],
        "notices": scene.extras["notices"],
        "normalization": scene.extras.get("normalization"),
        "method": ctx.method.name,
        "config": ctx.settings.to_dict(),
        "config_hash": config_hash(ctx.settings.to_dict()),
        "overrides": list(opts.overrides),
        "stages": {name: rec.to_dict() for name, rec in ctx.records.items()},
        "views": {"train": len(scene.train), "test": len(scene.test), "validation": len(scene.validation)},
        "holdout_psnr": geo_rec.info.get("test_psnr"),
        # the field's image measures on the held-out and the validation views (geometry stage)
        "image_measures": {k: geo_rec.info[k] for k in ("test_psnr", "test_ssim", "validation_psnr",
                                                         "validation_ssim") if geo_rec.info.get(k) is not None},
        "n_gaussians": int(fitted.features.shape[0]),
        "n_clusters": int(fitted.stats.get("n_clusters", 0)),
        "previews": [f"previews/{_file_name(v.name)}.png" for v in shown],
    }
    atomic_write_json(out / FIT_FILE, record)
    return out / FIT_FILE


def _file_name(view_name: str) -> str:
    return view_name.replace("/", "_")


def _say(enabled: bool):
    def say(msg: str) -> None:
        if enabled:
            print(msg, file=sys.stderr, flush=True)

    return say


def next_steps(fit_json: Path) -> list[str]:
    """What to do with a fitted capture, as commands."""
    import json

    out = fit_json.parent
    rec = json.loads(fit_json.read_text())
    views = json.loads((out / VIEWS_FILE).read_text())["train"]
    v = views[len(views) // 2]
    u, w = v["camera"]["width"] // 2, v["camera"]["height"] // 2
    return [f"look at the clusters beside the images: {out / 'previews'}/",
            ("select objects by clicks (view:x,y in pixels; repeat --click), or by a 2D mask of a view "
             f"(--mask {v['name']}:MASK.png): trase-bench select --fit {out} --click {v['name']}:{u},{w}"),
            f"look at it in the browser (time, modes, click selection, edits): trase-bench view --run {out}",
            f"render a clip: trase-bench render --run {out} --cameras orbit --mode clusters",
            f"edit it: trase-bench edit remove --run {out} --click {v['name']}:{u},{w} --out {out}-edited",
            f"{rec['n_clusters']} clusters over {rec['n_gaussians']} gaussians"
            + (f"; held-out PSNR {rec['holdout_psnr']:.2f} dB" if rec.get("holdout_psnr") is not None else "")
            + (f", SSIM {m['test_ssim']:.4f}" if (m := rec.get("image_measures") or {}).get("test_ssim") is not None
               else "")
            + (f"; validation PSNR {m['validation_psnr']:.2f} dB, SSIM {m['validation_ssim']:.4f}"
               if m.get("validation_psnr") is not None else "")]


__all__ = ["FitOptions", "fit_capture", "monocular", "next_steps"]
