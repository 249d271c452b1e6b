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
    -> int [H, W] track ids of a training view (None: the view has none)."""
    from masks.sampling import sample_pixels
    from trase.deformation import deformed
    from trase.devices import resolve_device
    from trase.fastpath import RasterizerPath, ViewWeights
    from trase.features import use_fastpath
    from trase.threads import torch_threads

    with torch_threads(cfg.torch_threads):
        dev = resolve_device(cfg.device)
        n = gaussians.num_gaussians
        gen = torch.Generator().manual_seed(int(cfg.seed))
        rng = np.random.default_rng(int(cfg.seed))
        encoder = make_encoder(n, cfg, temporal, gen).to(dev)
        t0 = time.perf_counter()
        ids, cams, usable = {}, {}, []
        for i, v in enumerate(views):
            m = load_ids(v)
            if m is None:
                continue
            m = np.asarray(m)
            if m.min(initial=0) < 0:
                raise IdentityTrainingError(f"view {v.name}: negative track id {int(m.min())}")
            ids[i] = torch.from_numpy(m.reshape(-1).astype(np.int64)).to(dev)
            cams[i] = (camera_at(v.camera, m.shape[0], m.shape[1], v.name), m.shape)
            usable.append(i)
        if not usable:
            raise IdentityTrainingError("no training view has tracked ids")
        n_classes = classes_for(cfg.n_classes, max(int(ids[i].max()) for i in usable))
        classifier = torch.nn.Linear(cfg.dim, n_classes)
        with torch.no_grad():  # torch's default initialisation, drawn from the run's generator
            bound = 1.0 / np.sqrt(cfg.dim)
            classifier.weight.uniform_(-bound, bound, generator=gen)
            classifier.bias.uniform_(-bound, bound, generator=gen)
        classifier = classifier.to(dev)
        if dev != gaussians.means.device:
            import copy

            gaussians = gaussians.copy().to(dev)
            deformation = None if deformation is None else copy.deepcopy(deformation).to(dev)

        fast = use_fastpath(cfg.fastpath, cfg.iterations, len(usable))
        path = (ViewWeights(gaussians, deformation, cache_dir, cfg.min_weight) if fast
                else RasterizerPath(gaussians, deformation))
        for i in usable:
            cam, shape = cams[i]
            path.register(i, views[i].name, cam, np.ones(shape, bool))
        if fast and cfg.iterations > 0:
            path.prepare_all()
        xyz = gaussians.means.detach()
        positions: dict[int, torch.Tensor] = {}  # per view: where the regulariser finds neighbours

        def positions_of(i: int) -> torch.Tensor:
            if not temporal:
                return xyz
            if i not in positions:
                with torch.no_grad():
                    positions[i] = deformed(gaussians, deformation, cams[i][0].time)[0].detach()
            return positions[i]

        timings = {"prepare": time.perf_counter() - t0}
        params = [{"params": encoder.parameters(), "lr": cfg.field_lr if temporal else cfg.lr, "eps": cfg.eps}]
        opt = torch.optim.Adam(params)
        opt_cls = torch.optim.Adam(classifier.parameters(), lr=cfg.classifier_lr, eps=cfg.classifier_eps)
        history: list[dict] = []
        t1 = time.perf_counter()
        for it in range(int(cfg.iterations)):
            vi = usable[int(rng.integers(len(usable)))]
            cam, (H, W) = cams[vi]
            if cfg.n_pixels and cfg.n_pixels < H * W:
                pix = sample_pixels(np.ones((H, W), bool), float(cfg.n_pixels), rng)
                pix = torch.from_numpy(np.ascontiguousarray(pix, dtype=np.int64)).to(dev)
            else:
                pix = torch.arange(H * W, device=dev)
            f = encoder(xyz, cam.time)  # [N, D]
            rendered = path.render(vi, f, pix)  # [P, D]
            loss = identity_loss(classifier(rendered), ids[vi][pix])
            stats = {"identity": float(loss.detach())}
            if cfg.reg3d_interval > 0 and (it + 1) % int(cfg.reg3d_interval) == 0:
                probs = torch.softmax(classifier(f), dim=1)
                reg = knn_consistency(positions_of(vi), probs, cfg.reg3d_k, cfg.reg3d_weight, cfg.reg3d_max_points,
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
        train = time.perf_counter() - t1
        timings.update(train=train, per_step=train / max(int(cfg.iterations), 1))
        return IdentityResult(encoder.cpu(), classifier.cpu(), history, timings, path.stats())


__all__ = ["IdentityResult", "IdentityTrainingError", "classes_for", "make_encoder", "train_identity"]
