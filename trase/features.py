"""Per-gaussian feature learning on frozen geometry (TRASE Sec. 3.2).

Each step: one random training view; masks sampled by a rule from ``masks.sampling`` (M');
pixels sampled with probability Np/(H*W) among pixels inside any mask (at mask resolution);
the (smoothed) gaussian features rendered at those pixels, by the frozen-geometry fast path
or by the rasterizer; the objective's loss; one Adam step on the features only.

Settings follow the public code: 32-d features initialised RGB2SH(U[0,1)), Adam lr 0.0025,
eps 1e-15, K=16 smoothing neighbours with 8 random slots per step. Deterministic for a seed
(numpy Generator for view/mask/pixel sampling, torch Generator for init and slot dropout).
Masks whose resolution differs from the camera are used at their own resolution with the
camera scaled to them (same aspect ratio required).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

from masks.sampling import sample_masks, sample_pixels
from trase.camera import Camera
from trase.devices import geometry_on, resolve_device
from trase.fastpath import RasterizerPath, ViewWeights
from trase.feature_config import FeatureConfig  # re-exported: the config of train_features
from trase.feature_run_state import FeatureCheckpoint, feature_progress
from trase.gaussians import rgb_to_sh_dc
from trase.objectives import PixelSample, get_objective
from trase.smoothing import NORM_EPS, knn_indices, smooth_features


class FeatureTrainingError(ValueError):
    user_facing = True


# "auto" fast path: a view's weights cost ~0.4-0.7 s to compute (a 160x120 view of a 30k
# gaussian room, every pixel with ~50 contributors, 2 CPU cores) and make a step cheaper when
# the view is drawn (synthetic HyperNeRF scene, 30k gaussians, Np 2000: 60-87 ms per step in
# runs beside another job, 170-215 ms rasterizing measured separately; not side by side), so
# they pay off from ~5 draws; scenes with hundreds or
# thousands of training views draw most views once or never in a few thousand steps.
# Both paths render the same features (<= 1e-5, trase.fastpath).
FASTPATH_MIN_USES = 5
NORM_REG_PIXELS = ("image", "sampled")


def use_fastpath(setting: bool | str, iterations: int, n_views: int) -> bool:
    """The fast-path decision for ``setting`` (True, False or "auto")."""
    if setting == "auto":
        return iterations >= FASTPATH_MIN_USES * max(n_views, 1)
    if isinstance(setting, bool):
        return setting
    raise FeatureTrainingError(f"fastpath must be true, false or 'auto', got {setting!r}")


@dataclasses.dataclass
class TrainResult:
    features: torch.Tensor  # [N, D] saved (smoothed over all K, as the public code saves)
    raw_features: torch.Tensor  # [N, D] the trained parameters before smoothing
    history: list[dict]  # per-step stats, sparsely (every log_every steps)
    timings: dict  # seconds: prepare (fast-path weights), train, per_step
    path_stats: dict  # fast path bytes per view etc.
    stopping: dict | None = None  # stop_interval > 0: the checks and where it stopped (trase.convergence)


def camera_at(camera: Camera, height: int, width: int, name: str) -> Camera:
    """``camera`` with its intrinsics scaled to a mask (or id map) of height x width of the same
    aspect ratio; another aspect is a one-line error naming the view."""
    if (camera.height, camera.width) == (height, width):
        return camera
    fx, fy = camera.width / width, camera.height / height
    if abs(fx - fy) > 0.02 * max(fx, fy):
        raise FeatureTrainingError(
            f"view {name}: masks are {width}x{height} but the image is {camera.width}x{camera.height} "
            "(different aspect ratio)"
        )
    K = camera.K.copy()
    K[0] /= fx
    K[1] /= fy
    return dataclasses.replace(camera, K=K, width=width, height=height)


def build_sample(maskset, rule: str, n_masks: float, n_pixels: float, rng: np.random.Generator,
                 view: int = -1) -> PixelSample:
    """Sample masks and pixels of one view -> PixelSample (pixels inside any mask only)."""
    idx = sample_masks(maskset, rule, n_masks, rng)
    pix = sample_pixels(maskset.covered, n_pixels, rng)  # [P] linear ids
    flat = maskset.masks.reshape(maskset.n, -1)
    member = flat[idx][:, pix].T if len(idx) else np.zeros((len(pix), 0), bool)  # [P, M]
    return PixelSample(
        pixels=torch.from_numpy(np.ascontiguousarray(pix, dtype=np.int64)),
        membership=torch.from_numpy(np.ascontiguousarray(member, dtype=bool)),
        mask_area=torch.from_numpy(maskset.area[idx].astype(np.float32)),
        pixel_mean_area=torch.from_numpy(maskset.pixel_mean_area.reshape(-1)[pix].astype(np.float32)),
        view=view,
    )


class _MaskCache:
    def __init__(self, load: Callable, views: Sequence, size: int) -> None:
        self.load, self.views, self.size = load, views, max(int(size), 1)
        self.cache: dict[int, object] = {}
        self.order: list[int] = []

    def __call__(self, i: int):
        if i in self.cache:
            self.order.remove(i)
            self.order.append(i)
            return self.cache[i]
        ms = self.load(self.views[i])
        self.cache[i] = ms
        self.order.append(i)
        if len(self.order) > self.size:
            del self.cache[self.order.pop(0)]
        return ms


def render_ready(features: torch.Tensor, knn: torch.Tensor, config: FeatureConfig,
                 generator: torch.Generator | None, every_neighbour: bool = False) -> torch.Tensor:
    """features [N, D] -> [N, D] as one training step renders them: smoothed over a random
    ``knn_keep`` of the K neighbour slots (``every_neighbour``: over all K, as the features are
    saved), then normalised again if ``config.renormalize``."""
    f = smooth_features(features, knn, None if every_neighbour else config.knn_keep, generator)
    if config.renormalize and knn.shape[1] > 0:  # K = 0: smooth_features already normalised
        f = torch.nn.functional.normalize(f, dim=1, eps=NORM_EPS)
    return f


def init_features(n: int, dim: int, generator: torch.Generator) -> torch.Tensor:
    """RGB2SH(U[0,1)) as the public code initialises gaussian features."""
    return rgb_to_sh_dc(torch.rand(n, dim, generator=generator))


def train_features(
    gaussians,
    deformation,
    views: Sequence,
    load_masks: Callable,
    config: FeatureConfig,
    cache_dir: str | Path | None = None,
    progress: bool = True,
    log_every: int = 50,
    checkpoint: str | Path | None = None,
    checkpoint_every_s: float = 30.0,
) -> TrainResult:
    """Train per-gaussian features [N, D] with geometry frozen. ``views`` have ``.camera`` and
    ``.name``; ``load_masks(view) -> MaskSet``. Returns the saved (smoothed) features.

    ``checkpoint``: a file where the loop's whole state is saved every ``checkpoint_every_s``
    seconds of training; when it exists at the start, training continues from it bit for bit
    (a killed or requeued job resumes inside the stage); removed when training ends."""
    from trase.threads import torch_threads

    ckpt = None if checkpoint is None else FeatureCheckpoint(Path(checkpoint), checkpoint_every_s)
    with torch_threads(config.torch_threads):
        return _train(gaussians, deformation, views, load_masks, config, cache_dir, progress, log_every, ckpt)


def _train(gaussians, deformation, views, load_masks, config, cache_dir, progress, log_every, ckpt) -> TrainResult:
    n = gaussians.num_gaussians
    _check_config(config)
    dev = resolve_device(config.device)
    gaussians, deformation = geometry_on(gaussians, deformation, dev)
    rng = np.random.default_rng(config.seed)
    gen = torch.Generator().manual_seed(config.seed)  # CPU draws, moved: alike on every device
    feats = torch.nn.Parameter(init_features(n, config.dim, gen).to(dev))  # [N, D]
    objective = get_objective(config.objective, **config.objective_params)
    whole_view = config.norm_reg_pixels == "image" and objective.uses_norm_regulariser
    knn = knn_indices(gaussians.means.detach(), config.knn).to(dev)  # [N, K]
    xyz = gaussians.means.detach()  # [N, 3]
    masks_of = _MaskCache(load_masks, views, config.mask_cache)

    t0 = time.perf_counter()
    usable, cams = _usable_views(views, masks_of, whole_view)
    usable, held = _held_out(views, usable, config)
    path = _render_path(gaussians, deformation, views, usable + held, cams, config, cache_dir)
    timings = {"prepare": time.perf_counter() - t0, "train": 0.0, "per_step": 0.0, "n_usable_views": len(usable)}
    if not usable or config.iterations <= 0 or n == 0:
        return _result(feats, knn, [], timings, path)

    step = _FeatureStep(config, objective, path, usable, masks_of, knn, xyz, whole_view, rng, gen, dev)
    plateau = _Criterion(step, held) if held else None
    history, t_train, start, done = _optimise(feats, step, views, progress, log_every, ckpt, plateau)
    timings.update(train=t_train, per_step=t_train / max(done, 1), resumed_from_step=start)  # t_train: all `done` steps
    stopping = None
    if config.stop_interval > 0:
        from trase.convergence import none_held_out

        stopping = (plateau.plateau.summary("held-out loss", config.iterations, [views[i].name for i in held])
                    if plateau is not None else none_held_out(config.iterations, (
                        f"no stop possible before the schedule's end ({config.iterations} steps): none held out"
                        if not config.stop_rule().can_stop_before(config.iterations, config.stop_interval) else
                        f"fewer than {2 * config.stop_holdout_every} training views with masks: none held out, "
                        "the full schedule")))
    return _result(feats, knn, history, timings, path, stopping)


def _held_out(views: Sequence, usable: list[int], config: FeatureConfig) -> tuple[list[int], list[int]]:
    """(trained, held out) indices of the usable views: none held out unless the stage stops
    when converged (``config.stop_interval``) and a stop could come before the schedule's end."""
    if not config.stop_rule().can_stop_before(config.iterations, config.stop_interval):
        return usable, []
    from trase.convergence import held_out_indices

    out = {usable[k] for k in held_out_indices([views[i] for i in usable], config.stop_holdout_every)}
    return [i for i in usable if i not in out], [i for i in usable if i in out]


def _check_config(config: FeatureConfig) -> None:
    """Settings that the loop cannot use, refused before any work (a user-facing error)."""
    if config.dim < 1:
        raise FeatureTrainingError(f"feature dim must be >= 1, got {config.dim}")
    try:
        config.stop_rule()
    except ValueError as exc:
        raise FeatureTrainingError(str(exc)) from None
    if config.stop_interval > 0 and config.stop_holdout_every < 2:
        raise FeatureTrainingError(f"stop_holdout_every must be >= 2 when stopping is on, got {config.stop_holdout_every}")
    if config.norm_reg_pixels not in NORM_REG_PIXELS:
        raise FeatureTrainingError(f"norm_reg_pixels must be one of {', '.join(NORM_REG_PIXELS)}, "
                                   f"got {config.norm_reg_pixels!r}")


def _usable_views(views: Sequence, masks_of: _MaskCache, whole_view: bool) -> tuple[list[int], dict]:
    """The indices of the views that have masks, and per such view its camera at mask resolution
    with the [H, W] bool pixels it renders: a view without masks teaches nothing."""
    usable, cams = [], {}
    for i, v in enumerate(views):
        ms = masks_of(i)
        if ms.n == 0 or not ms.covered.any():
            continue  # a view without masks teaches nothing
        # the whole view is rendered when the regulariser needs it, else only pixels in a mask
        covered = np.ones_like(ms.covered) if whole_view else ms.covered
        cams[i] = (camera_at(v.camera, ms.height, ms.width, v.name), covered)
        usable.append(i)
    return usable, cams


def _render_path(gaussians, deformation, views: Sequence, usable: list[int], cams: dict,
                 config: FeatureConfig, cache_dir):
    """The fast path or the rasterizer (``config.fastpath``, decided on the views given: the
    trained and the held-out ones) with every one registered; the fast path's weights are computed here, before the timed loop."""
    fast = use_fastpath(config.fastpath, config.iterations, len(usable))
    if fast:
        path = ViewWeights(gaussians, deformation, cache_dir, config.min_weight, config.max_cache_bytes)
    else:
        path = RasterizerPath(gaussians, deformation, config.render_backend)
    for i in usable:
        path.register(i, views[i].name, *cams[i])
    if fast and config.iterations > 0:
        path.prepare_all()  # weights of every view once, up front (cached on disk)
    return path


@dataclasses.dataclass
class _FeatureStep:
    """What every training step reads besides the features, gathered once so that the loop reads
    as the method does: draw a view and a sample, render, loss, Adam step."""

    config: FeatureConfig
    objective: object
    path: object  # ViewWeights or RasterizerPath, every usable view registered
    usable: list[int]
    masks_of: _MaskCache
    knn: torch.Tensor  # [N, K] neighbour indices
    xyz: torch.Tensor  # [N, 3] frozen canonical means
    whole_view: bool  # render every pixel of the view (the norm regulariser over the image)
    rng: np.random.Generator  # view, mask and pixel draws
    gen: torch.Generator  # smoothing slots and the objective's own draws
    dev: torch.device

    def draw(self) -> tuple[int, object, PixelSample]:
        """A random usable view, its MaskSet and a sample of its masks and pixels; ``rng`` draws
        the view, then the masks, then the pixels."""
        vi = self.usable[int(self.rng.integers(len(self.usable)))]
        ms = self.masks_of(vi)
        c = self.config
        sample = build_sample(ms, c.mask_rule, c.n_masks, c.n_pixels, self.rng, view=vi).to(self.dev)
        return vi, ms, sample

    def loss(self, feats: torch.Tensor, vi: int, ms, sample: PixelSample) -> tuple[torch.Tensor, dict]:
        """The objective's loss (plus its per-gaussian term, if any) on features [N, D] rendered
        at the sample's pixels of view ``vi``; sets ``sample.alpha`` / ``sample.image_features``
        where the objective reads them."""
        return self.loss_of(render_ready(feats, self.knn, self.config, self.gen), vi, ms, sample, self.gen)

    def loss_of(self, f: torch.Tensor, vi: int, ms, sample: PixelSample,
                gen: torch.Generator) -> tuple[torch.Tensor, dict]:
        """``loss`` on features ``f`` [N, D] ready to render; ``gen``: the objective's own draws."""
        if getattr(self.objective, "needs_alpha", False):
            # rendering is linear in the features, so rendering ones gives alpha = sum of weights
            with torch.no_grad():
                sample.alpha = self.path.render(vi, f.new_ones(f.shape[0], 1), sample.pixels)[:, 0]
        if self.whole_view:
            H, W = ms.height, ms.width
            sample.image_features = self.path.render(vi, f, torch.arange(H * W, device=self.dev))  # [H*W, D]
            rendered = sample.image_features[sample.pixels]  # [P, D]
        else:
            rendered = self.path.render(vi, f, sample.pixels)  # [P, D]
        loss, stats = self.objective(rendered, sample)
        extra = self.objective.gaussian_loss(f, self.xyz, gen)
        if extra is not None:
            loss = loss + extra
            stats["gaussian_loss"] = float(extra.detach())
        return loss, stats


class _Criterion:
    """The stopping criterion of the feature stage: the objective's mean loss over one fixed
    sample of each held-out view (drawn once, from its own stream, so every check measures the
    same pixels), on the features smoothed over all K neighbours (as the stage saves them) and
    renormalised as training renders them."""

    def __init__(self, step: _FeatureStep, held: list[int]) -> None:
        from trase.convergence import Plateau

        c = step.config
        self.step, self.plateau = step, Plateau(c.stop_rule())
        rng = np.random.default_rng([c.seed, 1])  # apart from the training draws
        # their masks kept here: read at every check through the training's cache they would push
        # the training views' masks out of it
        self.held = [(vi, step.masks_of(vi)) for vi in held]
        self.samples = [build_sample(ms, c.mask_rule, c.n_masks, c.n_pixels, rng, view=vi).to(step.dev)
                        for vi, ms in self.held]

    @torch.no_grad()
    def value(self, feats: torch.Tensor) -> float:
        s = self.step
        f = render_ready(feats, s.knn, s.config, None, every_neighbour=True)
        gen = torch.Generator().manual_seed(int(s.config.seed))  # the objective's draws, alike at every check
        losses = [float(s.loss_of(f, vi, ms, sample, gen)[0]) for (vi, ms), sample in zip(self.held, self.samples)]
        return float(np.mean(losses))

    def check(self, done: int, feats: torch.Tensor) -> bool:
        """After ``done`` steps: True when the stage should stop."""
        return self.plateau.due(done) and self.plateau.observe(done, self.value(feats), cap=self.step.config.iterations)


def _optimise(feats: torch.nn.Parameter, step: _FeatureStep, views: Sequence, progress: bool,
              log_every: int, ckpt: FeatureCheckpoint | None = None,
              criterion: _Criterion | None = None) -> tuple[list[dict], float, int, int]:
    """``config.iterations`` Adam steps on features [N, D] in place, fewer where ``criterion``
    says the loss has converged -> (history every ``log_every`` steps and the last, seconds of
    the loop, the step it resumed from, the steps done)."""
    config = step.config
    opt = torch.optim.Adam([feats], lr=config.lr, eps=config.eps)
    start, history, before = ckpt.load(feats, opt, step, criterion) if ckpt is not None else (0, [], 0.0)
    done = start
    t1 = time.perf_counter()
    with feature_progress(progress, config.iterations, start) as advance:
        for it in range(start, config.iterations):
            vi, ms, sample = step.draw()
            loss, stats = step.loss(feats, vi, ms, sample)
            opt.zero_grad(set_to_none=True)
            if loss.requires_grad:
                loss.backward()
                opt.step()
            if not torch.isfinite(loss):
                raise FeatureTrainingError(f"feature loss became non-finite at step {it} (view {views[vi].name})")
            done = it + 1
            stop = criterion is not None and criterion.check(done, feats.detach())
            if it % log_every == 0 or it == config.iterations - 1 or stop:
                history.append({"step": it, "loss": float(loss.detach()), **stats})
            advance(loss)
            if stop:
                break
            if ckpt is not None and it + 1 < config.iterations:
                ckpt.maybe_save(feats, opt, step, it + 1, history, before + time.perf_counter() - t1, criterion)
    if ckpt is not None:
        ckpt.remove()
    return history, before + time.perf_counter() - t1, start, done


def _result(feats: torch.Tensor, knn: torch.Tensor, history: list[dict], timings: dict, path,
            stopping: dict | None = None) -> TrainResult:
    """The saved features [N, D] (smoothed over all K neighbours, as the public code saves) and
    the raw parameters, both on the CPU."""
    with torch.no_grad():
        saved = smooth_features(feats.detach(), knn, None).cpu()
    return TrainResult(saved, feats.detach().cpu().clone(), history, timings, path.stats(), stopping)
