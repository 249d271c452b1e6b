"""Training identity encodings and the classifier on frozen geometry, from tracked ids.

Each step: one random training view; its pixels (all of them, or each kept with probability
n_pixels / (H W) as the project samples pixels); the identity encodings rendered there
(sum_i alpha_i T_i f_i, no background, as the public rasterizer composites them) by the
frozen-geometry fast path or the rasterizer; a linear classifier; cross-entropy / log(C)
against the view's track ids (0, "no track", is a class as in the public code). Every
``reg3d_interval`` steps the 3D regulariser is added: the class distributions of gaussians
against those of their k nearest (canonical positions for Gaussian Grouping; for SA4D the
deformed positions at the view's time, as its code uses them). Adam on the encodings (or the
field) and on the classifier.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence

import numpy as np
import torch

from trase.features import camera_at
from trase_bench_grouping.identity import IdentityField, IdentityTable
from trase_bench_grouping.losses import identity_loss, knn_consistency


class IdentityTrainingError(ValueError):
    user_facing = True


@dataclasses.dataclass
class IdentityResult:
    encoder: torch.nn.Module  # IdentityTable or IdentityField, on the CPU
    classifier: torch.nn.Linear  # on the CPU
    history: list[dict]
    timings: dict
    path_stats: dict


def classes_for(n_classes: int, max_id: int) -> int:
    """The classifier's outputs: ``n_classes`` (the public code's 256 fits DEVA's 8-bit ids),
    or more where a tracker numbered more tracks (one output per id, 0 = "no track" included)."""
    return max(int(n_classes), int(max_id) + 1)


def make_encoder(n: int, cfg, temporal: bool, generator: torch.Generator) -> torch.nn.Module:
    if temporal:
        return IdentityField(cfg.dim, cfg.field_width, cfg.field_depth, cfg.field_pos_freqs, cfg.field_time_freqs,
                             generator=generator)
    return IdentityTable(n, cfg.dim, generator=generator)


def train_identity(gaussians, deformation, views: Sequence, load_ids: Callable, cfg, temporal: bool = False,
                   cache_dir=None, progress: bool = False, log_every: int = 50) -> IdentityResult:
    """Train the encodings (``temporal``: SA4D's field) and the classifier; ``load_ids(view)``
    -> int [H, W] track ids of a training view (None: the view has none). ``progress``: a bar
    over the steps."""
    from trase.devices import geometry_on, resolve_device
    from trase.threads import torch_threads

    with torch_threads(cfg.torch_threads):
        dev = resolve_device(cfg.device)
        gen = torch.Generator().manual_seed(int(cfg.seed))
        rng = np.random.default_rng(int(cfg.seed))
        encoder = make_encoder(gaussians.num_gaussians, cfg, temporal, gen).to(dev)  # draws first from gen
        t0 = time.perf_counter()
        ids, cams = _view_ids(views, load_ids, dev)
        classifier = _classifier(cfg, classes_for(cfg.n_classes, max(int(m.max()) for m in ids.values())), gen, dev)
        gaussians, deformation = geometry_on(gaussians, deformation, dev)
        path = _render_path(gaussians, deformation, views, cams, cfg, cache_dir)
        timings = {"prepare": time.perf_counter() - t0}
        t1 = time.perf_counter()
        history = _optimise(encoder, classifier, path, _Positions(gaussians, deformation, cams, temporal), ids, cams,
                            views, cfg, gen, rng, progress, log_every)
        train = time.perf_counter() - t1
        timings.update(train=train, per_step=train / max(int(cfg.iterations), 1))
        return IdentityResult(encoder.cpu(), classifier.cpu(), history, timings, path.stats())


def _view_ids(views: Sequence, load_ids: Callable, dev) -> tuple[dict, dict]:
    """The training views with track ids -> ({view index: ids [H W] int64}, {view index:
    (camera at the ids' size, (H, W))}); none at all is an error."""
    ids, cams = {}, {}
    for i, v in enumerate(views):
        m = load_ids(v)
        if m is None:
            continue
        m = np.asarray(m)
        if m.min(initial=0) < 0:
            raise IdentityTrainingError(f"view {v.name}: negative track id {int(m.min())}")
        ids[i] = torch.from_numpy(m.reshape(-1).astype(np.int64)).to(dev)
        cams[i] = (camera_at(v.camera, m.shape[0], m.shape[1], v.name), m.shape)
    if not ids:
        raise IdentityTrainingError("no training view has tracked ids")
    return ids, cams


def _classifier(cfg, n_classes: int, gen: torch.Generator, dev) -> torch.nn.Linear:
    """The linear classifier, with torch's default initialisation drawn from the run's generator."""
    classifier = torch.nn.Linear(cfg.dim, n_classes)
    with torch.no_grad():
        bound = 1.0 / np.sqrt(cfg.dim)
        classifier.weight.uniform_(-bound, bound, generator=gen)
        classifier.bias.uniform_(-bound, bound, generator=gen)
    return classifier.to(dev)


def _render_path(gaussians, deformation, views: Sequence, cams: dict, cfg, cache_dir):
    """Where the encodings are rendered: the frozen-geometry fast path or the rasterizer, with
    every view that has ids registered."""
    from trase.fastpath import RasterizerPath, ViewWeights
    from trase.features import use_fastpath

    fast = use_fastpath(cfg.fastpath, cfg.iterations, len(cams))
    path = (ViewWeights(gaussians, deformation, cache_dir, cfg.min_weight) if fast
            else RasterizerPath(gaussians, deformation))
    for i, (cam, shape) in cams.items():
        path.register(i, views[i].name, cam, np.ones(shape, bool))
    if fast and cfg.iterations > 0:
        path.prepare_all()
    return path


class _Positions:
    """Where the 3D regulariser finds a view's neighbours: the canonical means, or (``temporal``)
    the means deformed to the view's time, computed once per view."""

    def __init__(self, gaussians, deformation, cams: dict, temporal: bool) -> None:
        self.gaussians, self.deformation, self.cams, self.temporal = gaussians, deformation, cams, temporal
        self.xyz = gaussians.means.detach()  # [N, 3]
        self.kept: dict[int, torch.Tensor] = {}

    def __call__(self, i: int) -> torch.Tensor:
        from trase.deformation import deformed

        if not self.temporal:
            return self.xyz
        if i not in self.kept:
            with torch.no_grad():
                self.kept[i] = deformed(self.gaussians, self.deformation, self.cams[i][0].time)[0].detach()
        return self.kept[i]


def _optimise(encoder, classifier, path, positions: _Positions, ids: dict, cams: dict, views: Sequence, cfg,
              gen: torch.Generator, rng: np.random.Generator, progress: bool, log_every: int) -> list[dict]:
    """``cfg.iterations`` Adam steps on the encodings and the classifier -> the history."""
    from masks.sampling import sample_pixels
    from trase.feature_run_state import feature_progress

    dev = positions.xyz.device
    usable = list(ids)
    opt = torch.optim.Adam([{"params": encoder.parameters(), "lr": cfg.field_lr if positions.temporal else cfg.lr,
                             "eps": cfg.eps}])
    opt_cls = torch.optim.Adam(classifier.parameters(), lr=cfg.classifier_lr, eps=cfg.classifier_eps)
    history: list[dict] = []
    with feature_progress(progress, int(cfg.iterations)) as advance:
        for it in range(int(cfg.iterations)):
            vi = usable[int(rng.integers(len(usable)))]
            cam, (H, W) = cams[vi]
            if cfg.n_pixels and cfg.n_pixels < H * W:
                pix = sample_pixels(np.ones((H, W), bool), float(cfg.n_pixels), rng)
                pix = torch.from_numpy(np.ascontiguousarray(pix, dtype=np.int64)).to(dev)
            else:
                pix = torch.arange(H * W, device=dev)
            f = encoder(positions.xyz, cam.time)  # [N, D]
            loss = identity_loss(classifier(path.render(vi, f, pix)), ids[vi][pix])  # rendered [P, D]
            stats = {"identity": float(loss.detach())}
            if cfg.reg3d_interval > 0 and (it + 1) % int(cfg.reg3d_interval) == 0:
                probs = torch.softmax(classifier(f), dim=1)
                reg = knn_consistency(positions(vi), probs, cfg.reg3d_k, cfg.reg3d_weight, cfg.reg3d_max_points,
                                      cfg.reg3d_sample_size, gen)
                loss = loss + reg
                stats["reg3d"] = float(reg.detach())
            opt.zero_grad(set_to_none=True)
            opt_cls.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            opt_cls.step()
            if not torch.isfinite(loss):
                raise IdentityTrainingError(f"identity loss became non-finite at step {it} (view {views[vi].name})")
            if it % log_every == 0 or it == cfg.iterations - 1:
                history.append({"step": it, "loss": float(loss.detach()), **stats})
            advance(loss)
    return history


__all__ = ["IdentityResult", "IdentityTrainingError", "classes_for", "make_encoder", "train_identity"]
