"""SAGA's feature training on frozen geometry.

Before training: each training view's masks get their 3D scale from the geometry's rendered
depth (``scales``); the scales of all views fit the quantile map. Each step: one training view
(every view once per round, in random order); ``n_scales`` of its masks' scales drawn at random,
plus one above every mask's and the view's smallest, each moved down at random toward the next
smaller mask's scale; pixels sampled inside the masks; the gaussian features (normalised, each
the mean of a random half of its 16 neighbours' unit features) rendered at those pixels (the
frozen-geometry fast path of ``trase.fastpath`` or the rasterizer); the loss of ``objective``;
one Adam step on the features and the gate together.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch

from trase.features import camera_at
from trase_bench_saga.objective import ScaleGate, pair_weights, saga_loss, scale_targets
from trase_bench_saga.scales import QuantileMap, mask_scales


class SagaTrainingError(ValueError):
    user_facing = True


@dataclasses.dataclass
class ViewMasks:
    """A training view's masks sorted by 3D scale, largest first."""

    index: int  # in the views passed to train
    camera: object  # at mask resolution
    order: np.ndarray  # [M] mask ids of the MaskSet, by descending scale
    scales: np.ndarray  # [M] their scales


@dataclasses.dataclass
class SagaResult:
    features: torch.Tensor  # [N, D] saved form: the mean of all K neighbours' unit features
    gate: dict  # ScaleGate.to_dict()
    quantiles: list  # QuantileMap knots
    upper_scale: float
    history: list
    timings: dict
    path_stats: dict
    scale_stats: dict


def view_scales(gaussians, deformation, camera, maskset, erode_min: int, min_alpha: float) -> np.ndarray:
    """[M] 3D scale of each mask of ``maskset`` (at the camera's resolution) from rendered depth."""
    from trase.prompts import render_depth

    depth, alpha = render_depth(gaussians, deformation, camera)
    H, W = depth.shape
    rows, cols = np.mgrid[0:H, 0:W]
    uv = np.stack([cols.reshape(-1) + 0.5, rows.reshape(-1) + 0.5], axis=1)
    points = camera.unproject(uv, depth.reshape(-1).astype(np.float64)).reshape(H, W, 3)
    surface = (alpha >= min_alpha) & (depth > 0)
    return mask_scales(points, surface, maskset.masks, erode_min)


def draw_scales(scales: np.ndarray, upper: float, n_scales: int, rng: np.random.Generator) -> tuple[list[int], np.ndarray]:
    """A view's scales [M] (descending) -> (mask index per sampled scale, -1 where above every
    mask; the sampled scales [S]): one above ``upper`` (the largest scale of all views), up to
    ``n_scales`` random masks' and the smallest, each moved down at random toward the next
    smaller mask's scale (toward 0 for the smallest; toward the largest scale below ``upper``
    for a scale at or above it)."""
    M = len(scales)
    picks = [-1, *[int(i) for i in rng.permutation(M)[:n_scales]], M - 1]
    below = scales[scales < upper]
    second = float(below.max()) if below.size else 0.0
    out = np.empty(len(picks), np.float64)
    index = []
    for k, i in enumerate(picks):
        s = upper * (1.0 + rng.random()) if i < 0 else float(scales[i])
        if s >= upper:
            s -= (s - second) * rng.random()
            index.append(-1)
        elif i != M - 1:
            s -= (s - float(scales[i + 1])) * rng.random()
            index.append(i)
        else:
            s -= s * rng.random()
            index.append(i)
        out[k] = s
    return index, out


def train_saga(gaussians, deformation, views, load_masks, cfg, cache_dir=None, progress: bool = False,
               log_every: int = 50) -> SagaResult:
    from trase.threads import torch_threads

    with torch_threads(cfg.torch_threads):
        return _train(gaussians, deformation, views, load_masks, cfg, cache_dir, progress, log_every)


def _train(gaussians, deformation, views, load_masks, cfg, cache_dir, progress, log_every) -> SagaResult:
    from trase.devices import geometry_on, resolve_device
    from trase.features import init_features
    from trase.smoothing import knn_indices, smooth_features

    if cfg.dim < 1 or cfg.n_scales < 0 or cfg.n_rays < 1:
        raise SagaTrainingError(f"features: dim {cfg.dim}, n_scales {cfg.n_scales} and n_rays {cfg.n_rays} "
                                "must be at least 1, 0 and 1")
    if cfg.norm_pixels not in ("image", "sampled"):
        raise SagaTrainingError(f"features.norm_pixels={cfg.norm_pixels!r}: choose image or sampled")
    dev = resolve_device(cfg.device)
    gaussians, deformation = geometry_on(gaussians, deformation, dev)
    n = gaussians.num_gaussians
    rng = np.random.default_rng(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    feats = torch.nn.Parameter(init_features(n, cfg.dim, gen).to(dev))  # [N, D]
    gate = ScaleGate(cfg.dim, gen).to(dev)
    knn = knn_indices(gaussians.means.detach(), cfg.knn).to(dev)  # [N, K]

    t0 = time.perf_counter()
    masks = _ViewsMasks(views, load_masks, gaussians, deformation, cfg)
    t_scales = time.perf_counter() - t0
    qmap, upper, scale_stats = _scale_map(masks.usable)
    t1 = time.perf_counter()
    path = _render_path(gaussians, deformation, views, masks, cfg, cache_dir)
    timings = {"scales": t_scales, "prepare": time.perf_counter() - t1, "train": 0.0, "per_step": 0.0,
               "n_usable_views": len(masks.usable)}
    history: list[dict] = []
    if not masks.usable or cfg.iterations <= 0 or n == 0:
        return _result(feats, knn, gate, qmap, upper, history, timings, path, scale_stats, smooth_features)
    t2 = time.perf_counter()
    history = _optimise(feats, gate, knn, path, masks, qmap, upper, cfg, rng, gen, progress, log_every)
    timings["train"] = time.perf_counter() - t2
    timings["per_step"] = timings["train"] / cfg.iterations
    return _result(feats, knn, gate, qmap, upper, history, timings, path, scale_stats, smooth_features)


class _ViewsMasks:
    """The training views with masks (``usable``, their masks sorted by 3D scale) and their
    masks, the first ``cfg.mask_cache`` views' kept in memory, the others read again."""

    def __init__(self, views, load_masks, gaussians, deformation, cfg) -> None:
        self.views, self.load_masks = views, load_masks
        self.kept: dict[int, object] = {}
        self.usable: list[ViewMasks] = []
        for i, v in enumerate(views):
            ms = load_masks(v)
            if ms.n == 0 or not ms.covered.any():
                continue
            cam = camera_at(v.camera, ms.height, ms.width, v.name)
            sc = view_scales(gaussians, deformation, cam, ms, cfg.erode_min, cfg.min_surface_alpha)
            order = np.argsort(-sc, kind="stable")
            self.usable.append(ViewMasks(i, cam, order, sc[order]))
            if len(self.kept) < cfg.mask_cache:
                self.kept[i] = ms

    def __call__(self, u: ViewMasks):
        ms = self.kept.get(u.index)
        return ms if ms is not None else self.load_masks(self.views[u.index])


def _scale_map(usable: list[ViewMasks]) -> tuple[QuantileMap, float, dict]:
    """The quantile map of every view's mask scales, the largest scale, and their statistics."""
    all_scales = np.concatenate([u.scales for u in usable]) if usable else np.zeros(0)
    upper = float(all_scales.max()) if all_scales.size else 0.0
    stats = {"n_masks": int(all_scales.size), "max": upper,
             **({f"p{p}": float(np.percentile(all_scales, p)) for p in (5, 50, 95)} if all_scales.size else {})}
    return QuantileMap.fit(all_scales), upper, stats


def _render_path(gaussians, deformation, views, masks: _ViewsMasks, cfg, cache_dir):
    """The frozen-geometry fast path or the rasterizer, every usable view registered with the
    pixels the loss reads (the whole image for ``norm_pixels=image``, else the masks' cover)."""
    from trase.fastpath import RasterizerPath, ViewWeights
    from trase.features import use_fastpath

    fast = use_fastpath(cfg.fastpath, cfg.iterations, len(masks.usable))
    path = (ViewWeights(gaussians, deformation, cache_dir, cfg.min_weight, cfg.max_cache_bytes) if fast
            else RasterizerPath(gaussians, deformation, cfg.render_backend))
    for k, u in enumerate(masks.usable):
        ms = masks(u)
        path.register(k, views[u.index].name, u.camera,
                      np.ones_like(ms.covered) if cfg.norm_pixels == "image" else ms.covered)
    if fast and cfg.iterations > 0 and masks.usable:
        path.prepare_all()
    return path


def _optimise(feats, gate, knn, path, masks: _ViewsMasks, qmap, upper: float, cfg, rng: np.random.Generator,
              gen: torch.Generator, progress: bool, log_every: int) -> list[dict]:
    """``cfg.iterations`` Adam steps on the features and the gate together, every usable view
    once per round in random order -> the history."""
    from trase.feature_run_state import feature_progress

    opt = torch.optim.Adam([feats, *gate.parameters()], lr=cfg.lr, eps=cfg.eps)
    stack: list[int] = []
    history: list[dict] = []
    with feature_progress(progress, int(cfg.iterations)) as advance:
        for it in range(cfg.iterations):
            if not stack:
                stack = [int(k) for k in rng.permutation(len(masks.usable))]
            k = stack.pop()
            step = _step_loss(feats, gate, knn, path, k, masks, qmap, upper, cfg, rng, gen)
            if step is None:  # fewer than two pixels drawn
                continue
            loss, norms, n_pixels, stats = step
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if not torch.isfinite(loss):
                name = masks.views[masks.usable[k].index].name
                raise SagaTrainingError(f"loss became non-finite at step {it} (view {name})")
            if it % log_every == 0 or it == cfg.iterations - 1:
                history.append({"step": it, "loss": float(loss.detach()), "norm": float(norms.mean().detach()),
                                "pixels": n_pixels, **stats})
            advance(loss)
    return history


def _step_loss(feats, gate, knn, path, k: int, masks: _ViewsMasks, qmap, upper: float, cfg,
               rng: np.random.Generator, gen: torch.Generator):
    """One step's loss on usable view ``k`` -> (loss, rendered norms [P or H W], pixels, stats),
    None where fewer than two pixels were drawn."""
    from trase.smoothing import smooth_features

    dev = feats.device
    u = masks.usable[k]
    ms = masks(u)
    index, sampled = draw_scales(u.scales, upper, cfg.n_scales, rng)
    keep = rng.random(ms.height * ms.width) < float(cfg.n_rays) / (ms.height * ms.width)
    pix = np.flatnonzero(keep & ms.covered.reshape(-1)).astype(np.int64)  # [P]
    if len(pix) < 2:
        return None
    member = torch.from_numpy(np.ascontiguousarray(ms.masks.reshape(ms.n, -1)[u.order][:, pix])).to(dev)
    targets = torch.stack([scale_targets(member, i) for i in index])  # [S, P, P]
    weights = pair_weights(torch.from_numpy(ms.pixel_mean_area.reshape(-1)[pix]).to(dev))
    rand = torch.rand(len(pix), len(pix), generator=gen).to(dev)
    q = torch.from_numpy(qmap(sampled)).to(dev, torch.float32)
    f = torch.nn.functional.normalize(smooth_features(feats, knn, cfg.knn_keep, gen), dim=1, eps=1e-12)
    pix_t = torch.from_numpy(pix).to(dev)
    if cfg.norm_pixels == "image":
        image = path.render(k, f, torch.arange(ms.height * ms.width, device=dev))
        rendered, norms = image[pix_t], image.norm(dim=1)
    else:
        rendered = path.render(k, f, pix_t)
        norms = rendered.norm(dim=1)
    loss, stats = saga_loss(rendered, gate(q), targets, weights, rand, cfg.positive_below, cfg.negative_above)
    return loss + cfg.norm_weight * (1.0 - norms.mean()) ** 2, norms, len(pix), stats


def _result(feats, knn, gate, qmap, upper, history, timings, path, scale_stats, smooth_features) -> SagaResult:
    with torch.no_grad():
        saved = smooth_features(feats.detach(), knn, None).cpu()
    return SagaResult(saved, gate.to_dict(), qmap.to_list(), upper, history, timings, path.stats(), scale_stats)
