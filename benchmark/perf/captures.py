"""``trase-bench perf captures``: ``trase-bench fit`` on the built-in HyperNeRF-format scene
written as a capture in each layout (a nerfies capture with COLMAP points only and two images
the notebook dropped, a COLMAP folder with times.json, transforms json), then one click per
object of interest (the interior point of its largest appearance among the training views)
through ``trase-bench select``: IoU of the selection against the synthetic instance maps at
every training view, per object and for all objects together, and the stage times of ``fit``.

The capture is the scene's training views; the test views are never used (the two dropped
images are test views, ignored by the reader).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

QUICK_SET = ["geometry.train.iterations=100", "method.features.iterations=50"]


def _interest_clicks(scene, ids: list[int]) -> dict[int, tuple[str, int, int]]:
    """Per object id: (view, x, y), the deepest interior pixel of its largest training-view area."""
    import cv2

    best: dict[int, tuple[int, str, int, int]] = {}
    for v in scene.train:
        inst = cv2.imread(str(scene.truth.instance_maps[v.name]), cv2.IMREAD_UNCHANGED)
        for i in ids:
            m = (inst == i).astype(np.uint8)
            area = int(m.sum())
            if area and area > best.get(i, (0,))[0]:
                dist = cv2.distanceTransform(m, cv2.DIST_L2, 3)
                y, x = np.unravel_index(int(np.argmax(dist)), dist.shape)
                best[i] = (area, v.name, int(x), int(y))
    return {i: b[1:] for i, b in best.items()}


def _ious(scene, masks: dict[str, np.ndarray], ids: list[int]) -> list[float]:
    import cv2

    out = []
    for v in scene.train:
        gt = np.isin(cv2.imread(str(scene.truth.instance_maps[v.name]), cv2.IMREAD_UNCHANGED), ids)
        pred = masks[v.name]
        union = int((gt | pred).sum())
        out.append(1.0 if union == 0 else float((gt & pred).sum()) / union)
    return out


def run(quick: bool, echo, out_dir: Path) -> dict:
    from benchmark.capture_fit import FitOptions, fit_capture
    from benchmark.capture_select import select_clicks
    from benchmark.captures.write import clear, write_colmap_folder, write_nerfies_capture, write_transforms
    from benchmark.datasets import load_scene
    from benchmark.datasets.synthetic import ensure_synthetic

    size = "tiny" if quick else "small"
    scene = load_scene("hypernerf", ensure_synthetic("hypernerf", size=size))
    ids = scene.truth.interest_ids
    clicks = _interest_clicks(scene, ids)
    root = Path(out_dir) / "captures"
    views, pts, cols = scene.train, scene.points, scene.point_colors
    layouts = {
        "nerfies": lambda d: write_nerfies_capture(views, pts, cols, d, unlisted=scene.test[:2]),
        "colmap": lambda d: write_colmap_folder(views, pts, cols, d),
        "transforms": lambda d: write_transforms(views, pts, cols, d),
    }
    echo(f"scene: synthetic hypernerf ({size}), {len(views)} training views at "
         f"{views[0].camera.width}x{views[0].camera.height}; objects of interest {ids}; clicks {clicks}")
    result = {"scene": {"dataset": "hypernerf", "size": size, "views": len(views), "objects": ids,
                        "clicks": {str(k): v for k, v in clicks.items()}}, "layouts": {}}
    for name, write in layouts.items():
        cap, fit_dir = root / name, root / f"fit-{name}"
        clear(cap)
        clear(fit_dir)
        write(cap)
        t0 = time.perf_counter()
        fit_json = fit_capture(FitOptions(cap, fit_dir, overrides=QUICK_SET if quick else [], progress=True))
        wall = time.perf_counter() - t0
        rec = json.loads(fit_json.read_text())
        per_object = {}
        for i, (view, x, y) in clicks.items():
            sel = select_clicks(fit_dir, [f"{_capture_name(rec, view)}:{x},{y}"], fit_dir / f"selection-{i}")
            per_object[str(i)] = float(np.mean(_ious(scene, _by_view(sel["masks"]), [i])))
        everything = select_clicks(fit_dir, [f"{_capture_name(rec, v)}:{x},{y}" for v, x, y in clicks.values()])
        union = _ious(scene, _by_view(everything["masks"]), ids)
        stages = {k: v["seconds"] for k, v in rec["stages"].items()}
        result["layouts"][name] = {"fit_seconds": round(wall, 1), "stages": stages,
                                   "iou_all_objects": float(np.mean(union)), "iou_worst_view": float(np.min(union)),
                                   "iou_per_object": per_object, "notices": rec["notices"],
                                   "n_gaussians": rec["n_gaussians"], "n_clusters": rec["n_clusters"]}
        echo(f"{name:<10} fit {wall:6.1f}s ({', '.join(f'{k} {v:.0f}s' for k, v in stages.items())}); "
             f"IoU all objects {np.mean(union):.3f} (worst view {np.min(union):.3f}); per object "
             + ", ".join(f"{k}: {v:.3f}" for k, v in per_object.items()))
    return result


def _capture_name(rec: dict, view: str) -> str:
    """The capture's name for a scene view (transforms names carry their folder)."""
    return f"images/{view}" if rec["format"] == "transforms" else view


def _by_view(masks: dict) -> dict:
    return {Path(k).name: v for k, v in masks.items()}
