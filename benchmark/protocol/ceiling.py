"""Label ceiling of a geometry on a synthetic scene: what *perfect per-gaussian labels* score.

Why: a method's mIoU mixes two errors, the geometry's (blurred, semi-transparent or misplaced
gaussians) and the segmentation's (wrong clusters, wrong prompts). On the built-in synthetic
scenes every training view has an exact instance map, so each gaussian can be given the
object it shows most: its compositing weights summed per instance id over all training views
(rendering is linear in the features, so the gradient of sum_p onehot(id_p) . f(p) with
respect to per-gaussian features is exactly these votes [N, K]). The gaussians whose largest
vote is an object of interest, rendered with the method's rule and threshold, give the
ceiling: a segmentation of this geometry cannot be expected to beat it by much. It is an
estimate, not a strict bound: the majority vote mislabels a few gaussians where objects touch
(synthetic Immersive, ground-truth geometry: 0.894, where the true object ids give 0.914, and
a method scored 0.911). The cluster-level "oracle" asks the same of the method's own clusters.

Only synthetic scenes have instance maps; real data gets no ceiling.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from benchmark.datasets.truth import MANIFEST
from benchmark.errors import UserError
from masks.generate import read_instance_map  # [H, W] int64 ids; one-line error naming the file


class CeilingError(UserError):
    user_facing = True


def instance_votes(gaussians, deformation, cameras: Sequence, instance_maps: Sequence[np.ndarray],
                   n_ids: int) -> np.ndarray:
    """[N, n_ids] float64: per gaussian, its compositing weight summed over the pixels of each
    instance id, over all (camera, instance map) pairs. Ids >= n_ids are ignored."""
    from trase.prompts import geometry_at
    from trase.render import rasterize

    n = gaussians.num_gaussians
    votes = np.zeros((n, n_ids), np.float64)
    if n == 0:
        return votes
    for cam, ids in zip(cameras, instance_maps):
        if ids.shape != (cam.height, cam.width):
            raise CeilingError(f"instance map of view {cam.name!r} is {ids.shape[1]}x{ids.shape[0]} but the "
                               f"camera renders {cam.width}x{cam.height} (WxH)")
        m, q, s, o = geometry_at(gaussians, deformation, cam.time)
        f = torch.zeros(n, n_ids, dtype=m.dtype, requires_grad=True)
        with torch.enable_grad():
            out = rasterize(m, q, s, o, cam, features=f)
            ids_t = torch.from_numpy(ids)
            inside = ids_t < n_ids
            onehot = torch.zeros(ids.shape + (n_ids,), dtype=m.dtype)
            onehot[inside] = torch.nn.functional.one_hot(ids_t[inside], n_ids).to(m.dtype)
            (out.features * onehot).sum().backward()
        votes += f.grad.double().numpy()
    return votes


def truth_selection(votes: np.ndarray, object_ids: Sequence[int]) -> np.ndarray:
    """[N] bool: gaussians seen at all whose largest vote is one of ``object_ids``."""
    if votes.shape[0] == 0:
        return np.zeros(0, bool)
    seen = votes.sum(1) > 0
    return seen & np.isin(votes.argmax(1), np.asarray(list(object_ids), dtype=np.int64))


def synthetic_truth(scene) -> tuple[list[int], dict[str, Path], int]:
    """(ids of the objects of interest, instance map path per view name, number of ids) of a
    synthetic scene (``scene.truth``)."""
    truth = scene.truth
    if truth is None:
        raise CeilingError(f"{scene.root}: not a synthetic scene (no {MANIFEST}); no ceiling")
    if not truth.interest_ids:
        raise CeilingError(f"{truth.manifest_path}: no objects of interest in the synthetic manifest")
    return truth.interest_ids, truth.instance_maps, truth.n_ids


# votes come from at most this many training views, evenly spread: a 17-camera x 300-frame
# scene has 5100, each vote a render and a backward; 600 see every object at many times
MAX_VOTE_VIEWS = 600


def label_ceiling(gaussians, deformation, scene, gts: Sequence[np.ndarray], rule: str = "alone",
                  threshold: float = 0.5):
    """-> (ScoreResult "v1" of the truth-labelled gaussians on the test views, info dict)."""
    from benchmark.scoring import score_masks
    from trase.memoised_deformation import memoised
    from trase.segment import RULES, render_alpha, render_visible

    ids, paths, n_ids = synthetic_truth(scene)
    views = [v for v in scene.train if v.name in paths]
    if len(views) > MAX_VOTE_VIEWS:  # evenly spread over the list (cameras x frames)
        views = [views[round(i * (len(views) - 1) / (MAX_VOTE_VIEWS - 1))] for i in range(MAX_VOTE_VIEWS)]
    if not views:
        raise CeilingError(f"{scene.root}: no training view has an instance map; no ceiling")
    vote_maps = [read_instance_map(paths[v.name]) for v in views]  # [H, W] ids each
    votes = instance_votes(gaussians, deformation, [v.camera for v in views], vote_maps, n_ids)
    sel = truth_selection(votes, ids)
    if rule not in RULES:
        raise CeilingError(f"unknown segmentation rule {rule!r}; choose one of {', '.join(RULES)}")
    render = render_alpha if rule == "alone" else render_visible
    every = slice(None, None, TRAINING_VIEW_STRIDE)  # each training view has its own time: not memoised
    on_training_views = training_view_score(gaussians, deformation, sel, [v.camera for v in views[every]],
                                            vote_maps[every], ids, render, threshold)
    deformation = memoised(deformation, gaussians.means)  # the test views are rendered twice (objects, movers)
    alphas = [render(gaussians, deformation, sel, v.camera) for v in scene.test]  # [H, W] each
    preds = [a >= threshold for a in alphas]
    names = [f"{i:05d}" for i in range(len(scene.test))]
    score = score_masks(dict(zip(names, preds)), dict(zip(names, gts)), "v1")
    maps = instance_maps_of_test_views(scene)
    info = {"n_selected": int(sel.sum()), "n_views": len(views), "rule": rule, "training_views": on_training_views,
            "object_alpha": object_alpha_stats(alphas, gts, threshold),
            "objects": per_object_stats(gaussians, votes, scene.truth, maps, alphas, threshold)}
    movers = scene.truth.mover_ids
    if movers:
        sel_m = truth_selection(votes, movers)
        alphas_m = [render(gaussians, deformation, sel_m, v.camera) for v in scene.test]
        info["movers"] = per_object_stats(gaussians, votes, scene.truth, maps, alphas_m, threshold, ids=movers)
        per_frame = {f.frame: f.iou("v1") for f in score.frames}
        info["mover_frames"] = mover_frame_split(scene.truth, maps, [per_frame.get(n) for n in names])
    return score, info


# the ceiling's selection is also scored on every TRAINING_VIEW_STRIDE-th vote view (at most 120)
TRAINING_VIEW_STRIDE = 5


def training_view_score(gaussians, deformation, sel: np.ndarray, cameras: Sequence, maps: Sequence[np.ndarray],
                        ids: Sequence[int], render, threshold: float) -> dict:
    """The truth-labelled selection ``sel`` scored (v1 mIoU) on training views against their
    instance maps (the objects of interest together). Why: a geometry that fits its objects
    worse loses here as much as on the test views; one that generalises worse to new
    viewpoints loses on the test views only."""
    from benchmark.scoring import score_masks

    names = [f"{i:05d}" for i in range(len(cameras))]
    preds = {n: render(gaussians, deformation, sel, c) >= threshold for n, c in zip(names, cameras)}  # [H, W]
    truth = {n: np.isin(m, np.asarray(list(ids), dtype=np.int64)) for n, m in zip(names, maps)}  # [H, W]
    miou = float(score_masks(preds, truth, "v1").miou) if names else float("nan")
    return {"miou": round(miou, 4) if np.isfinite(miou) else None, "n_views": len(names)}


def instance_maps_of_test_views(scene) -> list[np.ndarray | None]:
    """The instance maps [H, W] of the test views, in ``scene.test``'s order (None for a view
    without one), read once for every statistic below."""
    paths = scene.truth.instance_maps
    return [read_instance_map(paths[v.name]) if v.name in paths else None for v in scene.test]


def per_object_stats(gaussians, votes: np.ndarray, truth, maps: Sequence[np.ndarray | None],
                     alphas: Sequence[np.ndarray], threshold: float = 0.5, ids: Sequence[int] | None = None) -> dict:
    """Per object of interest (or per object of ``ids``; by name): how solid it renders in the
    test views (``object_alpha_stats`` over its own instance-map pixels, from the render of
    every truth-labelled gaussian of those objects by the run's rule; without ``spill``, which
    that render cannot tell apart from the other objects) and how opaque the gaussians labelled
    with it are (median, share below 0.5). Why: a geometry can look right in colour and still
    be a fog of faint gaussians that no labelling turns into a mask, or miss an object that
    passes in front of the objects of interest; this says which object and how. ``maps``: the
    test views' instance maps (``instance_maps_of_test_views``); views without one are left out (the
    counts say how many pixels were used)."""
    wanted = set(truth.interest_ids if ids is None else ids)
    seen = votes.sum(1) > 0
    label = votes.argmax(1) if votes.shape[0] else np.zeros(0, np.int64)
    opacity = gaussians.opacities.detach().reshape(-1).cpu().numpy().astype(np.float64)
    pairs = [(a, m) for a, m in zip(alphas, maps) if m is not None]
    out = {}
    for obj in truth.objects:
        if obj.id not in wanted:
            continue
        mine = seen & (label == obj.id)
        op = opacity[mine]
        alpha = object_alpha_stats([a for a, _ in pairs], [m == obj.id for _, m in pairs], threshold)
        alpha.pop("spill")
        out[obj.name] = {
            **alpha,
            "gaussians": int(mine.sum()),
            "opacity_median": round(float(np.median(op)), 4) if op.size else None,
            "opacity_below_half": round(float((op < 0.5).mean()), 4) if op.size else None,
        }
    return out


# a mover "touches" an object of interest within this many pixels (the 5x5 neighbourhood)
TOUCH_RADIUS = 2


def mover_frame_split(truth, maps: Sequence[np.ndarray | None], ious: Sequence[float | None]) -> dict:
    """The ceiling's per-frame IoU (``ious``, one per test view) split by whether a mover (a
    moving object not of interest, ``SceneTruth.mover_ids``) touches an object of interest in
    the frame's instance map (``maps``, as ``instance_maps_of_test_views``): passing in front of it or
    beside it. Why: an occluder that the reconstruction misses leaves the object's gaussians
    showing where the ground truth has the occluder, which ``object_alpha`` counts as spill.
    Frames without an instance map or without a score (both masks empty) are left out."""
    import cv2

    kernel = np.ones((2 * TOUCH_RADIUS + 1,) * 2, np.uint8)
    touched, other = [], []
    for ids, iou in zip(maps, ious):
        if ids is None or iou is None or not np.isfinite(iou):
            continue
        near = cv2.dilate(np.isin(ids, truth.mover_ids).astype(np.uint8), kernel) > 0
        (touched if (near & np.isin(ids, truth.interest_ids)).any() else other).append(float(iou))

    def mean(x):
        return round(float(np.mean(x)), 4) if x else None

    return {"frames": len(touched), "miou": mean(touched), "other_frames": len(other), "other_miou": mean(other)}


def object_alpha_stats(alphas: Sequence[np.ndarray], gts: Sequence[np.ndarray], threshold: float = 0.5) -> dict:
    """How solid and how tight the objects of interest render: over the ground-truth pixels of
    every test frame, the mean alpha and the share below ``threshold`` (holes: pixels of the
    object that the segmentation rule cannot predict however well the gaussians are labelled),
    and the pixels predicted outside the ground truth per ground-truth pixel (spill: what the
    objects' gaussians cover beyond their outlines; the false positives no labelling removes)."""
    inside = [np.asarray(a, np.float64)[np.asarray(g, bool)] for a, g in zip(alphas, gts)]
    vals = np.concatenate(inside) if inside else np.zeros(0)
    if vals.size == 0:
        return {"mean_in_gt": None, "holes": None, "spill": None, "gt_pixels": 0}
    outside = sum(int((np.asarray(a) >= threshold)[~np.asarray(g, bool)].sum()) for a, g in zip(alphas, gts))
    return {"mean_in_gt": round(float(vals.mean()), 4), "holes": round(float((vals < threshold).mean()), 4),
            "spill": round(outside / vals.size, 4), "gt_pixels": int(vals.size)}


__all__ = [
    "CeilingError",
    "instance_maps_of_test_views",
    "instance_votes",
    "label_ceiling",
    "mover_frame_split",
    "object_alpha_stats",
    "per_object_stats",
    "synthetic_truth",
    "training_view_score",
    "truth_selection",
]
