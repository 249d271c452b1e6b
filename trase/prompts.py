"""Prompts: from a click or a 2D mask in a (novel) view to gaussian clusters.

* Click (paper, supplementary "Testing implementation details"): render depth at the click's
  camera and time, unproject the pixel with K^-1 and c2w, take the nearest *deformed*
  gaussian at that time (KD-tree), return its cluster. A click on a pixel with rendered alpha
  below ``min_alpha`` hits nothing (-1): there is no surface to lift it to. The "weight" rule
  instead takes the cluster rendered most under the cursor (a 3x3 window), the "feature" rule
  the cluster whose mean feature is nearest the feature rendered there, the "front" rule the
  nearest to the camera of the clusters holding a share of that weight; see ``click_to_cluster``.
* 2D mask prompt (the public code's text-prompt path: a Grounded-SAM mask): pixels with a rendered
  surface are lifted the same way. Rule ``cover``: a cluster is chosen when at least
  ``min_cover`` of its own lifted pixels in the view lie inside the mask, the intersection over
  the cluster's area that Gaussian Grouping's mask prompt thresholds at 0.7
  (``ext/grounded_sam.py``). Rule ``share`` (the paper's text-prompt rule, "the number of
  associated gaussians of a cluster is more than a threshold"): each lifted mask pixel takes its
  nearest gaussian, and a cluster is chosen when it holds at least ``min_share`` of the distinct
  gaussians hit (a share rather than the paper's count, which would change with the image size).
  Rule ``iou`` (default): the clusters whose lifted pixels in the view together best match the
  mask (the largest intersection over union).
  Why ``iou`` by default: a share of the mask depends on the other clusters under it, so an
  object cut into parts keeps only its largest part (D-NeRF hook, one figure in six clusters:
  ``share`` chose the torso, IoU 0.857 against the alpha of the validation views, ``cover`` the
  whole figure, 0.956); and where an object shares its clusters with its surroundings, no
  cluster passes ``cover``'s threshold and the mask selects nothing, where ``iou`` takes the
  mixed cluster when it raises the IoU (docs/notes/text-prompts.md, "The iou rule").

The benchmark's clicks from ground truth and the oracle live in benchmark.protocol.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import torch
from scipy.spatial import cKDTree

from trase.camera import Camera
from trase.clustering import _centres, normalise
from trase.deformation import deformed
from trase.render import pixel_weights, rasterize

CLICK_RULES = ("depth", "weight", "feature", "front")
# the "front" rule's least share of the window's weight: the only share tried that chose no
# occluder on the selection scenes (0.2-0.33 did; docs/notes/cpu-constants.md, "The click rule")
FRONT_SHARE = 0.4
# What a positive click does on a cluster that is already selected: "nothing" (the paper's one
# click, one cluster), or "next": it adds the cluster its rule ranks next there among those
# neither selected nor ruled out. Why "next" exists: a person clicks again where the object is
# still missing; where the pixel's first cluster is already in the selection, the part still
# missing belongs to another cluster under the same pixel (docs/notes/corrective-clicks.md,
# "A click on a selected cluster").
ON_SELECTED = ("nothing", "next")
MASK_RULES = ("cover", "share", "iou")
DEFAULT_MASK_RULE = "iou"  # chosen on the selection scenes (docs/notes/text-prompts.md)
MASK_MIN_COVER = 0.7  # Gaussian Grouping's intersection-over-area threshold of its mask prompt
# the "share" rule's least share of the distinct gaussians a mask's lifted pixels hit (the paper
# names no value)
MASK_MIN_SHARE = 0.05


class PromptError(ValueError):
    user_facing = True


@dataclasses.dataclass(frozen=True)
class Click:
    u: float  # pixel x (continuous; pixel centre of column c is c + 0.5)
    v: float  # pixel y
    view: str = ""  # name of the view the click was made in
    time: float | None = None  # None: the camera's time
    view_index: int = -1  # index of that view among the scene's test views (-1: unknown)
    positive: bool = True  # False: a negative click ("not this"), which removes and keeps out a cluster


@torch.no_grad()
def geometry_at(gaussians, deformation, t: float):
    """(means, quats, scales, opacities) of the deformed gaussians at time t (detached)."""
    m, q, s = deformed(gaussians, deformation, t)
    return m.detach(), q.detach(), s.detach(), gaussians.opacities.detach()


@torch.no_grad()
def render_depth(gaussians, deformation, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """-> (depth [H, W], alpha [H, W]) of the full scene at camera.time."""
    m, q, s, o = geometry_at(gaussians, deformation, camera.time)
    if m.shape[0] == 0:
        z = np.zeros((camera.height, camera.width), np.float32)
        return z, z.copy()
    out = rasterize(m, q, s, o, camera, features=torch.zeros(m.shape[0], 1, dtype=m.dtype))
    return out.depth.cpu().numpy(), out.alpha.cpu().numpy()


def lift_pixels(
    gaussians, deformation, camera: Camera, uv: np.ndarray, min_alpha: float = 0.5,
    depth_alpha: tuple[np.ndarray, np.ndarray] | None = None, allowed: np.ndarray | None = None,
) -> np.ndarray:
    """Pixels uv [P, 2] -> [P] int64 id of the nearest deformed gaussian to the unprojected
    surface point at camera.time (of the ``allowed`` [N] bool ones, where given); -1 where the
    rendered alpha is below min_alpha."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    out = np.full(uv.shape[0], -1, np.int64)
    if uv.shape[0] == 0 or gaussians.num_gaussians == 0:
        return out
    depth, alpha = depth_alpha if depth_alpha is not None else render_depth(gaussians, deformation, camera)
    H, W = depth.shape
    col = np.clip(np.floor(uv[:, 0]).astype(np.int64), 0, W - 1)
    row = np.clip(np.floor(uv[:, 1]).astype(np.int64), 0, H - 1)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    ok = inside & (alpha[row, col] >= min_alpha) & (depth[row, col] > 0)
    if not ok.any():
        return out
    pts = camera.unproject(uv[ok], depth[row[ok], col[ok]])
    means = geometry_at(gaussians, deformation, camera.time)[0].cpu().numpy().astype(np.float64)
    ids = np.arange(means.shape[0]) if allowed is None else np.flatnonzero(allowed)  # [M] candidates
    if ids.size == 0:
        return out
    _, idx = cKDTree(means[ids]).query(pts, k=1)
    out[ok] = ids[np.asarray(idx, dtype=np.int64)]
    return out


def click_to_cluster(gaussians, deformation, camera: Camera, click: Click, labels: np.ndarray,
                     min_alpha: float = 0.5, rule: str = "depth", radius: int = 1,
                     features: np.ndarray | None = None, front_share: float = FRONT_SHARE,
                     exclude=()) -> int:
    """One click -> cluster id (-1 when the click hits no surface), never one of ``exclude``
    (each rule then picks its best cluster among the others).

    ``rule="depth"`` (the paper's): rendered depth -> 3D point -> nearest deformed gaussian.
    ``rule="weight"``: the cluster with the largest compositing weight in the
    (2 radius + 1)^2 window at the click, i.e. what is rendered under the cursor. Why: on
    semi-transparent reconstructed surfaces the rendered (expected) depth falls between the
    object and what lies behind it, and the nearest gaussian there can be the background's
    (synthetic Immersive, CPU geometry: a click with alpha 1.0, weights 0.76 object / 0.22
    background chose the background cluster: mIoU 0.10, oracle 0.77).
    ``rule="feature"`` (needs ``features`` [N, D], else ``gaussians.features``): the feature
    rendered in that window (the compositing-weighted sum, what the contrastive loss fits to
    the 2D masks) is compared by cosine with each cluster's mean feature; the nearest cluster
    wins. Why: where an object's gaussians are semi-transparent the weight under the cursor
    can be mostly the background's, while the rendered feature is the object's
    (docs/notes/cpu-constants.md, "The click rule", has the measurements).
    ``rule="front"``: of the clusters holding at least ``front_share`` of the window's weight,
    the one nearest the camera (the weight-averaged depth of its gaussians there). Why: a
    person clicks what is in front; where a semi-transparent object blends with the wall
    behind it, the wall can hold more of the weight and of the rendered feature than the
    object (docs/notes/cpu-constants.md, "The click rule")."""
    if rule not in CLICK_RULES:
        raise PromptError(f"unknown click rule {rule!r}; choose one of {', '.join(CLICK_RULES)}")
    if rule == "feature" and features is None:
        if getattr(gaussians, "features", None) is None:
            raise PromptError("click rule 'feature' needs the gaussians' features")
        features = gaussians.features.detach().cpu().numpy()  # the editor's models carry them
    cam = camera if click.time is None else camera.with_time(click.time)
    labels = np.asarray(labels, dtype=np.int64)
    ruled_out = np.isin(labels, np.fromiter(exclude, np.int64)) if len(exclude) else None  # [N] bool
    labels = labels if ruled_out is None else np.where(ruled_out, -1, labels)
    if rule == "front" and not 0.0 < front_share <= 1.0:
        raise PromptError(f"front_share must be in (0, 1], got {front_share}")
    if rule in ("weight", "feature", "front"):
        # front also needs the gaussians' depths: their deformed geometry, computed once
        geometry = geometry_at(gaussians, deformation, cam.time) if rule == "front" and gaussians.num_gaussians else None
        window = window_weights(gaussians, deformation, cam, click.u, click.v, min_alpha, radius, geometry)
        if window is None:
            return -1
        idx, w = window
        if rule == "weight":
            return _heaviest_cluster(idx, w, labels)
        if rule == "front":
            means = geometry[0][torch.from_numpy(idx)].cpu().numpy().astype(np.float64)  # [K, 3]
            depth = cam.world_to_camera(means)[:, 2]  # [K] camera z of each pair's gaussian
            return _front_cluster(idx, w, depth, labels, front_share)
        return _nearest_cluster_feature(idx, w, labels, features)
    allowed = None if ruled_out is None else ~ruled_out
    gid = int(lift_pixels(gaussians, deformation, cam, np.array([[click.u, click.v]]), min_alpha, allowed=allowed)[0])
    return -1 if gid < 0 else int(labels[gid])


def positive_pick(pick, ruled_out: set[int], selected: set[int], on_selected: str = "nothing") -> int:
    """The cluster a positive click adds (-1: none): ``pick(exclude)``, the click rule's choice
    among the clusters not in ``exclude``, taken outside ``ruled_out``; where that one is in
    ``selected`` already, ``on_selected`` "next" takes its choice outside both (and keeps the
    first where there is none)."""
    if on_selected not in ON_SELECTED:
        raise PromptError(f"unknown on_selected {on_selected!r}; choose one of {', '.join(ON_SELECTED)}")
    k = pick(set(ruled_out))
    if k in selected and on_selected == "next":
        other = pick(set(ruled_out) | set(selected))
        return other if other >= 0 else k
    return k


def select_in_order(clicks: list[Click], pick, universe: set[int],
                    on_selected: str = "nothing") -> tuple[list[int], list[int]]:
    """Clicks taken in order -> (the clusters selected, sorted; the cluster of each click, -1 for
    none). ``pick(i, exclude)``: the cluster click ``i`` reads among those of ``universe`` not in
    ``exclude`` (-1: none). A positive click adds its cluster, chosen among those no negative
    click has ruled out; where that cluster is selected already, ``on_selected`` "next" adds the
    one it reads among those neither selected nor ruled out instead ("nothing": none). A
    negative click removes the selected cluster under it (its choice among the selected ones;
    where none of them is there, its choice among all) and rules it out of later clicks."""
    selected: list[int] = []
    excluded: set[int] = set()
    per_click = []
    for i, click in enumerate(clicks):
        if click.positive:
            k = positive_pick(functools.partial(pick, i), excluded, set(selected), on_selected)
            if k >= 0 and k not in selected:
                selected.append(k)
        else:
            k = pick(i, universe - set(selected)) if selected else -1  # a selected cluster under it
            k = k if k >= 0 else pick(i, excluded)
            if k >= 0:
                excluded.add(k)
                selected = [c for c in selected if c != k]
        per_click.append(k)
    return sorted(selected), per_click


def clicks_to_clusters(gaussians, deformation, cameras: list[Camera], clicks: list[Click], labels: np.ndarray,
                       on_selected: str = "nothing", **rule) -> tuple[list[int], list[int]]:
    """A sequence of clicks, each in its view's camera (``cameras[i]`` for ``clicks[i]``) ->
    (the clusters selected, sorted; the cluster of each click in order, -1 for none), taken in
    order by select_in_order (``on_selected``: ON_SELECTED). ``rule``: click_to_cluster's
    keyword arguments."""
    if len(cameras) != len(clicks):
        raise PromptError(f"{len(clicks)} clicks need as many cameras, got {len(cameras)}")
    all_ids = {int(k) for k in np.unique(np.asarray(labels, dtype=np.int64)) if k >= 0}
    picks = [functools.partial(click_to_cluster, gaussians, deformation, camera, click, labels, **rule)
             for camera, click in zip(cameras, clicks)]
    return select_in_order(clicks, lambda i, exclude: picks[i](exclude=exclude), all_ids, on_selected)


@torch.no_grad()
def window_weights(gaussians, deformation, camera: Camera, u: float, v: float, min_alpha: float,
                    radius: int, geometry: tuple | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """(gaussian ids [K], compositing weights [K] float64) of every (gaussian, pixel) pair in
    the (2 radius + 1)^2 window of pixels around (u, v); None off the image, on an empty
    scene, or where the click pixel's alpha is below min_alpha. ``geometry``: the deformed
    (means, quats, scales, opacities) at camera.time where the caller has them already."""
    if radius < 0:
        raise PromptError(f"click window radius must be >= 0, got {radius}")
    W, H = camera.width, camera.height
    if not (0 <= u < W and 0 <= v < H) or gaussians.num_gaussians == 0:
        return None
    col, row = int(np.floor(u)), int(np.floor(v))
    rows = np.arange(max(row - radius, 0), min(row + radius, H - 1) + 1)
    cols = np.arange(max(col - radius, 0), min(col + radius, W - 1) + 1)
    window = (rows[:, None] * W + cols[None, :]).reshape(-1)
    centre = int(np.flatnonzero(window == row * W + col)[0])
    m, q, s, o = geometry if geometry is not None else geometry_at(gaussians, deformation, camera.time)
    pw = pixel_weights(m, q, s, o, camera, torch.from_numpy(window))
    indptr = pw.indptr.cpu().numpy()
    w = pw.weights.cpu().numpy().astype(np.float64)
    if w[indptr[centre]:indptr[centre + 1]].sum() < min_alpha:
        return None
    return pw.indices.cpu().numpy(), w


def _heaviest_cluster(idx: np.ndarray, w: np.ndarray, labels: np.ndarray) -> int:
    """The cluster with the largest summed weight (-1 when no weight is on a cluster).
    Ties: the lowest cluster id."""
    lab = np.asarray(labels, dtype=np.int64)[idx]
    ok = lab >= 0
    if not ok.any():
        return -1
    return int(np.argmax(np.bincount(lab[ok], weights=w[ok])))


def _front_cluster(idx: np.ndarray, w: np.ndarray, depth: np.ndarray, labels: np.ndarray, share: float) -> int:
    """Of the clusters holding >= ``share`` of the window's weight on clusters, the one with the
    smallest weight-averaged depth (-1 when no weight is on a cluster). Ties: the lowest id."""
    lab = np.asarray(labels, dtype=np.int64)[idx]
    ok = lab >= 0
    if not ok.any():
        return -1
    weight = np.bincount(lab[ok], weights=w[ok])  # [C]
    total = weight.sum()
    if not np.isfinite(total) or total <= 0.0:
        return -1
    mean_depth = np.bincount(lab[ok], weights=w[ok] * depth[ok], minlength=weight.size) / np.maximum(weight, 1e-300)
    eligible = np.flatnonzero(weight >= share * total)
    if eligible.size == 0:  # the weight spread over many clusters, none holding the share: the heaviest
        eligible = np.array([int(np.argmax(weight))])
    return int(eligible[np.argmin(mean_depth[eligible])])


def _nearest_cluster_feature(idx: np.ndarray, w: np.ndarray, labels: np.ndarray, features: np.ndarray) -> int:
    """The cluster whose centre (the normalised mean of its unit features, as the similarity
    filter's) has the largest cosine with the rendered feature sum_k w_k f_k of the window;
    -1 when there is no cluster or the rendered feature is zero. Ties: the lowest cluster id."""
    lab = np.asarray(labels, dtype=np.int64)
    feats = np.asarray(features, dtype=np.float64)  # [N, D]
    if feats.shape[0] != lab.shape[0]:
        raise PromptError(f"features have {feats.shape[0]} rows for {lab.shape[0]} labels")
    rendered = (w[:, None] * feats[idx]).sum(axis=0)  # [D]
    norm = np.linalg.norm(rendered)
    clustered = lab >= 0
    if not clustered.any() or not np.isfinite(norm) or norm == 0.0:
        return -1
    ids, centres = _centres(normalise(feats[clustered]), lab[clustered])  # [C], [C, D]
    return int(ids[np.argmax(centres @ (rendered / norm))])


def _strided_pixels(mask: np.ndarray, max_points: int) -> np.ndarray:
    """[P, 2] pixel centres (u, v) of an evenly strided, deterministic subset of at most
    ``max_points`` of the True pixels of ``mask`` [H, W]."""
    rows, cols = np.nonzero(mask)
    step = max(1, int(np.ceil(rows.size / max_points)))
    return np.stack([cols[::step] + 0.5, rows[::step] + 0.5], axis=1)


def mask_to_clusters(gaussians, deformation, camera: Camera, mask: np.ndarray, labels: np.ndarray,
                     rule: str = DEFAULT_MASK_RULE, min_cover: float = MASK_MIN_COVER, min_share: float = MASK_MIN_SHARE,
                     max_points: int = 40000, min_alpha: float = 0.5) -> list[int]:
    """2D mask [H, W] of ``camera`` -> sorted ids of the clusters it selects (module docstring:
    ``cover``: >= min_cover of the cluster's lifted pixels in the view are inside the mask;
    ``share``: the cluster holds >= min_share of the distinct gaussians the mask's pixels hit;
    ``iou``: the clusters whose lifted pixels in the view best match the mask, best_iou_clusters).

    At most ``max_points`` pixels are lifted (of the whole view for ``cover`` and ``iou``, of the
    mask for ``share``; an evenly strided, deterministic subset)."""
    if rule not in MASK_RULES:
        raise PromptError(f"unknown mask rule {rule!r}; choose one of {', '.join(MASK_RULES)}")
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != (camera.height, camera.width):
        raise PromptError(f"mask prompt is {mask.shape[1]}x{mask.shape[0]} but the camera is "
                          f"{camera.width}x{camera.height}")
    if not mask.any():
        return []
    lab_all = np.asarray(labels, dtype=np.int64)
    if rule == "share":
        gids = lift_pixels(gaussians, deformation, camera, _strided_pixels(mask, max_points), min_alpha)
        hit = np.unique(gids[gids >= 0])  # [M] distinct gaussians hit
        if hit.size == 0:
            return []
        values, counts = np.unique(lab_all[hit], return_counts=True)
        share = counts / hit.size
        return sorted(int(v) for v, s in zip(values, share) if v >= 0 and s >= min_share)
    uv = _strided_pixels(np.ones_like(mask), max_points)  # [P, 2] over the whole view
    gids = lift_pixels(gaussians, deformation, camera, uv, min_alpha)
    ok = gids >= 0
    lab = lab_all[gids[ok]]
    inside = mask[uv[ok, 1].astype(np.int64), uv[ok, 0].astype(np.int64)]
    keep = lab >= 0
    lab, inside = lab[keep], inside[keep]
    if lab.size == 0:
        return []
    seen = np.bincount(lab)  # [K] lifted pixels per cluster
    within = np.bincount(lab, weights=inside.astype(np.float64), minlength=seen.size)
    if rule == "iou":
        return best_iou_clusters(within, seen - within, float(np.count_nonzero(inside)))
    chosen = (within > 0) & (within >= min_cover * np.maximum(seen, 1))
    return [int(k) for k in np.flatnonzero(chosen)]


def no_cluster_reason(rule: str, min_cover: float = MASK_MIN_COVER, min_share: float = MASK_MIN_SHARE) -> str:
    """Why a mask chose no cluster under ``rule``, for the line that says so."""
    return {"cover": f"none has {min_cover:.0%} of its visible pixels inside the mask",
            "share": f"none holds {min_share:.0%} of the gaussians the mask's pixels hit"}.get(
        rule, "no surface under the mask")


def best_iou_clusters(inside: np.ndarray, outside: np.ndarray, mask_area: float) -> list[int]:
    """Sorted ids of the clusters whose union best matches a mask: ``inside`` [K] / ``outside``
    [K], each cluster's pixels in and out of the mask (disjoint across clusters), ``mask_area``
    the mask's pixels. IoU(S) = sum(in) / (area + sum(out)); adding a cluster raises it exactly
    when its in/out ratio exceeds the current IoU, so the best set is a prefix of the clusters
    ordered by that ratio, taken while each raises the IoU."""
    order = sorted(np.flatnonzero(inside > 0), key=lambda k: (-(inside[k] / max(outside[k], 1e-9)), -inside[k], k))
    chosen, got, union = [], 0.0, float(mask_area)
    for k in order:
        if got * (union + outside[k]) >= (got + inside[k]) * union:  # IoU would not rise
            break
        chosen.append(int(k))
        got, union = got + float(inside[k]), union + float(outside[k])
    return sorted(chosen)
