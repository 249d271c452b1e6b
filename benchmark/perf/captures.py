"""``trase-bench perf captures [--dataset D]``: ``trase-bench fit`` on a built-in scene written
as a capture in each layout, then one click per object of interest (the interior point of its
largest appearance among the training views) through ``trase-bench select``: IoU of the
selection against the synthetic instance maps at every training view, per object and for all
objects together, the geometry's label ceiling on those views, and the stage times of ``fit``.

Layouts: a monocular scene (the default HyperNeRF format, or NeRF-DS) is written as a nerfies
capture with COLMAP points only and two images the notebook dropped, a COLMAP folder with
times.json, and transforms json; a multi-view scene (Neu3D, Immersive, Technicolor) as the
COLMAP folder and transforms json only (the nerfies capture is one phone's video).

Two mask sources: ``classical`` (the offline generator, what ``fit`` uses without SAM) and
``files`` (SAM-like masks cut from the scene's instance maps by the synthetic generator,
handed to ``fit`` as masks made elsewhere: ``masks.generator=files``), standing in for SAM,
which cannot be downloaded here. The second source reuses the first's reconstruction (one
stage cache for the suite). The capture is the scene's training views; the test views are
never used (the two dropped images are test views, ignored by the reader).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

QUICK_SET = ["geometry.train.iterations=100", "method.features.iterations=50"]


def _interest_clicks(maps: dict[str, np.ndarray], ids: list[int]) -> dict[int, tuple[str, int, int]]:
    """Per object id: (view, x, y), the deepest interior pixel of its largest training-view area."""
    import cv2

    best: dict[int, tuple[int, str, int, int]] = {}
    for name, inst in maps.items():
        for i in ids:
            m = (inst == i).astype(np.uint8)
            area = int(m.sum())
            if area and area > best.get(i, (0,))[0]:
                dist = cv2.distanceTransform(m, cv2.DIST_L2, 3)
                y, x = np.unravel_index(int(np.argmax(dist)), dist.shape)
                best[i] = (area, name, int(x), int(y))
    return {i: b[1:] for i, b in best.items()}


def training_view_ceiling(fit_dir: Path, maps: dict[str, np.ndarray], ids: list[int], n_ids: int) -> dict[str, float]:
    """Per object of interest (and all together): the mean training-view IoU of the gaussians
    whose largest instance vote is that object, rendered by the fit's render rule and threshold
    (the label ceiling of benchmark.protocol.ceiling, on the capture's own geometry and
    training views): what a perfect clustering and click could reach on this geometry."""
    from benchmark.captures.select import fitted_capture
    from benchmark.protocol.ceiling import instance_votes, truth_selection
    from trase.segment import render_masks

    _, _, fitted, cap = fitted_capture(fit_dir)
    views = [v for v in cap.train if _scene_name(v.name) in maps]
    g, deform = fitted.gaussians, fitted.deformation
    rule, threshold = str(fitted.config.render_rule), float(fitted.config.alpha_threshold)
    votes = instance_votes(g, deform, [v.camera for v in views], [maps[_scene_name(v.name)] for v in views], n_ids)
    out = {}
    for label, chosen in [*((str(i), [i]) for i in ids), ("all", ids)]:
        sel = truth_selection(votes, chosen)
        masks = render_masks(g, deform, sel, [v.camera for v in views], threshold, rule)
        preds = {_scene_name(v.name): m for v, m in zip(views, masks)}
        out[label] = float(np.mean(_ious(maps, preds, chosen)))
    return out


def _ious(maps: dict[str, np.ndarray], masks: dict[str, np.ndarray], ids: list[int]) -> list[float]:
    """IoU per training view of the predicted masks and the union of objects ``ids``."""
    out = []
    for name, inst in maps.items():
        gt = np.isin(inst, ids)
        pred = masks[name]
        union = int((gt | pred).sum())
        out.append(1.0 if union == 0 else float((gt & pred).sum()) / union)
    return out


def run(quick: bool, echo, out_dir: Path, dataset: str = "hypernerf") -> dict:
    from benchmark.captures.write import (
        clear,
        write_colmap_folder,
        write_nerfies_capture,
        write_transforms,
    )
    from benchmark.datasets import get_dataset, load_scene
    from benchmark.datasets.synthetic import ensure_synthetic

    size = "tiny" if quick else "small"
    spec = get_dataset(dataset)
    scene = load_scene(spec.key, ensure_synthetic(spec.key, size=size))
    from masks.generate import read_instance_map

    ids = scene.truth.interest_ids
    maps = {v.name: read_instance_map(scene.truth.instance_maps[v.name]) for v in scene.train}  # read once
    clicks = _interest_clicks(maps, ids)
    root = Path(out_dir) / "captures"  # one stage cache for every scene and layout
    base = root / spec.key
    views, pts, cols = scene.train, scene.points, scene.point_colors
    sam_like = base / "masks-sam-like"
    if not sam_like.is_dir():
        import masks as masklib
        from masks.generators import make_generator

        masklib.generate_scene_masks(views, make_generator("synthetic", seed=0), sam_like, progress=False,
                                     instance_maps=maps)
    sources = {"classical": [], "files": ["masks.generator=files", f"masks.dir={sam_like}"]}
    layouts = {
        "nerfies": lambda d: write_nerfies_capture(views, pts, cols, d, unlisted=scene.test[:2]),
        "colmap": lambda d: write_colmap_folder(views, pts, cols, d),
        "transforms": lambda d: write_transforms(views, pts, cols, d),
    }
    if not spec.monocular:  # a nerfies capture is one phone's video
        del layouts["nerfies"]
    echo(f"scene: synthetic {spec.key} ({size}), {len(views)} training views at "
         f"{views[0].camera.width}x{views[0].camera.height}; objects of interest {ids}; clicks {clicks}")
    result = {"scene": {"dataset": spec.key, "size": size, "views": len(views), "objects": ids,
                        "clicks": {str(k): v for k, v in clicks.items()}}, "layouts": {}}
    for name, write in layouts.items():
        cap = base / name
        if not (cap / ".complete").is_file():  # written once: its images' mtimes key the cache
            clear(cap)
            write(cap)
            (cap / ".complete").touch()
        for source, sets in sources.items():
            result["layouts"][f"{name}/{source}"] = _fit_and_select(
                maps, scene.truth.n_ids, cap, cap.parent / f"fit-{name}-{source}", root / ".cache",
                [*sets, *(QUICK_SET if quick else [])], clicks, ids, echo, f"{name}/{source}")
    return result


def _fit_and_select(maps, n_ids: int, cap: Path, fit_dir: Path, cache: Path, sets: list[str], clicks, ids, echo,
                    label) -> dict:
    """Fit one capture with one mask source, then one click per object and all clicks at once."""
    from benchmark.captures.fit import FitOptions, fit_capture
    from benchmark.captures.select import select_clicks

    t0 = time.perf_counter()
    fit_json = fit_capture(FitOptions(cap, fit_dir, overrides=sets, cache_dir=cache, progress=True))
    wall = time.perf_counter() - t0
    rec = json.loads(fit_json.read_text())
    per_object = {}
    for i, (view, x, y) in clicks.items():
        sel = select_clicks(fit_dir, [f"{_capture_name(rec, view)}:{x},{y}"], fit_dir / f"selection-{i}")
        per_object[str(i)] = float(np.mean(_ious(maps, _by_view(sel["masks"]), [i])))
    everything = select_clicks(fit_dir, [f"{_capture_name(rec, v)}:{x},{y}" for v, x, y in clicks.values()])
    union = _ious(maps, _by_view(everything["masks"]), ids)
    stages = {k: {"seconds": v["seconds"], "reused": v["skipped"]} for k, v in rec["stages"].items()}
    ceiling = training_view_ceiling(fit_dir, maps, ids, n_ids)
    echo(f"{label:<21} fit {wall:6.1f}s ("
         + ", ".join(f"{k} {v['seconds']:.0f}s{' reused' if v['reused'] else ''}" for k, v in stages.items())
         + f"); IoU all objects {np.mean(union):.3f} (worst view {np.min(union):.3f}); per object "
         + ", ".join(f"{k}: {v:.3f}" for k, v in per_object.items())
         + "; geometry ceiling " + ", ".join(f"{k}: {v:.3f}" for k, v in ceiling.items()))
    return {"geometry_ceiling": ceiling, "fit_seconds": round(wall, 1), "stages": stages,
            "iou_all_objects": float(np.mean(union)), "iou_worst_view": float(np.min(union)),
            "iou_per_object": per_object, "notices": rec["notices"],
            "n_gaussians": rec["n_gaussians"], "n_clusters": rec["n_clusters"]}


def _capture_name(rec: dict, view: str) -> str:
    """The capture's name for a scene view (transforms names carry their folder)."""
    return f"images/{view}" if rec["format"] == "transforms" else view


def _by_view(masks: dict) -> dict:
    return {_scene_name(k): v for k, v in masks.items()}


def _scene_name(capture_name: str) -> str:
    """The scene's view name of a capture's view (transforms names carry their images/ folder;
    a multi-view scene's names keep their camera folder: cam01/00001)."""
    return capture_name.removeprefix("images/")
