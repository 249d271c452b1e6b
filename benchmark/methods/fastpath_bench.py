"""Measure one feature-learning iteration through the frozen-geometry fast path versus the
rasterizer, on a synthetic scene with ground-truth geometry.

    python -m benchmark.methods.fastpath_bench [--dataset nerfds] [--n-pixels 5000] [--reps 5]

Both paths run the same step (same view, same sampled masks and pixels, same smoothing slots):
smooth features -> render at the sampled pixels -> objective -> backward. Prints the median
seconds of each path (render+objective+backward, and render+backward alone), the speed-up,
the loss difference (must be <= 1e-5) and the fast path's bytes per view.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path


def bench(dataset: str = "nerfds", n_pixels: int = 5000, reps: int = 5, view_index: int = 0,
          size: str = "small", backend: str = "auto", threads: int = 0) -> dict:
    import numpy as np
    import torch

    if threads:
        torch.set_num_threads(threads)

    import masks as masklib
    from benchmark.datasets import get_dataset, load_scene
    from benchmark.datasets.synthetic.cache import ensure_synthetic
    from benchmark.io import read_json
    from masks.generators.base import make_generator
    from trase.checkpoint import load_synthetic_geometry
    from trase.fastpath import RasterizerPath, ViewWeights
    from trase.features import build_sample, init_features
    from trase.objectives import get_objective
    from trase.smoothing import knn_indices, smooth_features

    scene_dir = ensure_synthetic(dataset, size=size)
    scene = load_scene(dataset, scene_dir, gt_dir=scene_dir / "gt_masks")
    spec = get_dataset(dataset)
    g, deform, _ = load_synthetic_geometry(scene_dir / "synthetic" / "geometry.npz")
    view = scene.train[view_index]
    manifest_path = scene_dir / "synthetic" / "manifest.json"
    manifest = read_json(manifest_path, "synthetic manifest")
    work = Path(tempfile.mkdtemp(prefix="fastpath-bench-"))
    masklib.generate_scene_masks([view], make_generator("synthetic", seed=0), work / "masks", progress=False,
                                 instance_maps={view.name: manifest_path.parent / manifest["instances"][view.name]})
    ms = masklib.load(masklib.mask_path(work / "masks", view.name))
    sample = build_sample(ms, "random", spec.n_masks, n_pixels, np.random.default_rng(0), view=0)
    gen = torch.Generator().manual_seed(0)
    feats0 = init_features(g.num_gaussians, 32, gen)
    knn = knn_indices(g.means.detach(), 16)
    keep = torch.randperm(16, generator=gen)[:8]
    objective = get_objective("trase")

    fast = ViewWeights(g, deform, work / "pw")
    slow = RasterizerPath(g, deform, backend)
    for p in (fast, slow):
        p.register(0, view.name, view.camera, ms.covered)
    t0 = time.perf_counter()
    fast.get(0)
    t_precompute = time.perf_counter() - t0

    def step(path, with_loss=True):
        """with_loss: the whole iteration (smooth -> render -> objective -> backward);
        else only render + backward from an already smoothed leaf tensor."""
        f = torch.nn.Parameter(feats0.clone())
        if not with_loss:
            leaf = smooth_features(f, knn[:, keep], None).detach().requires_grad_(True)
            t = time.perf_counter()
            r = path.render(0, leaf, sample.pixels)
            r.backward(torch.ones_like(r))
            return time.perf_counter() - t, 0.0, r.detach()
        t = time.perf_counter()
        sm = smooth_features(f, knn[:, keep], None)
        r = path.render(0, sm, sample.pixels)
        loss, _ = objective(r, sample)
        loss.backward()
        return time.perf_counter() - t, float(loss.detach()), r.detach()

    if threads:  # set here: loading the scene (numba, OpenCV) may reset torch's thread count
        torch.set_num_threads(threads)
    step(fast), step(slow)  # warm-up (numba JIT, caches)
    out = {}
    for name, path in (("fast", fast), ("rasterizer", slow)):
        full = [step(path) for _ in range(reps)]
        render_only = [step(path, with_loss=False)[0] for _ in range(reps)]
        out[name] = {"iteration_s": statistics.median(t for t, _, _ in full),
                     "render_backward_s": statistics.median(render_only),
                     "loss": full[0][1], "features": full[0][2]}
    diff_loss = abs(out["fast"]["loss"] - out["rasterizer"]["loss"])
    diff_feat = float((out["fast"]["features"] - out["rasterizer"]["features"]).abs().max())
    return {
        "dataset": dataset, "n_gaussians": g.num_gaussians, "image": f"{view.camera.width}x{view.camera.height}",
        "n_sampled_pixels": sample.n_pixels, "n_masks_sampled": sample.n_masks,
        "fast_iteration_s": out["fast"]["iteration_s"], "raster_iteration_s": out["rasterizer"]["iteration_s"],
        "speedup_iteration": out["rasterizer"]["iteration_s"] / out["fast"]["iteration_s"],
        "fast_render_backward_s": out["fast"]["render_backward_s"],
        "raster_render_backward_s": out["rasterizer"]["render_backward_s"],
        "speedup_render_backward": out["rasterizer"]["render_backward_s"] / out["fast"]["render_backward_s"],
        "loss_abs_diff": diff_loss, "feature_max_abs_diff": diff_feat,
        "precompute_s": t_precompute, "bytes_per_view": fast.stats()["bytes_per_view_max"],
        "backend": backend, "torch_threads": torch.get_num_threads(),
        "note": "iteration_s includes the objective on Np x Np pairs, identical in both paths",
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dataset", default="nerfds")
    ap.add_argument("--n-pixels", type=int, default=5000)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--size", default="small")
    ap.add_argument("--backend", default="auto")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    a = ap.parse_args(argv)
    print(json.dumps(bench(a.dataset, a.n_pixels, a.reps, size=a.size, backend=a.backend, threads=a.threads),
                     indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
