"""Compile trase's numba kernels into numba's on-disk cache before they are first needed.

Why: on a fresh checkout the kernels compile on first use, ~35 s on 2 cores, inside whichever
stage calls them first (the reconstruction's first step, the first feature step). Running a
miniature of every stage's kernel calls in another process while the machine does something
else (the benchmark runs it while it generates a synthetic scene) takes that time off the
critical path. The miniature goes through the same functions as the real stages, so the
kernels are compiled with the signatures those calls use; what it leaves behind is numba's
cache and nothing else (its scene, checkpoints and features go to a temporary directory).

``python -m trase.precompile`` runs it and prints how many kernels it compiled (or that every
one was cached).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


@dataclasses.dataclass
class _View:
    """What reconstruction and feature training read from a view."""

    name: str
    camera: object  # trase.camera.Camera
    image_path: Path

    @property
    def time(self) -> float:
        return self.camera.time


class _CompileCounter:
    """Counts numba compilations (cache misses) while installed."""

    def __init__(self) -> None:
        self.compiled: list[str] = []

    def __enter__(self):
        from numba.core import event

        outer = self

        class _Listener(event.Listener):
            def on_start(self, ev):
                pass

            def on_end(self, ev):
                d = ev.data["dispatcher"]
                outer.compiled.append(f"{d.py_func.__module__}.{d.py_func.__qualname__}")

        self._listener = _Listener()
        event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc) -> None:
        from numba.core import event

        event.unregister("numba:compile", self._listener)


def _tiny_scene(root: Path, n_views: int = 3, width: int = 32, height: int = 24):
    """Views with images on disk, initial points and colours: two coloured blobs in front of
    the cameras, enough for every code path to run (deformation, densification, masks)."""
    from PIL import Image

    from trase.camera import Camera, intrinsics, look_at

    rng = np.random.default_rng(0)
    views = []
    for i in range(n_views):
        ang = -0.3 + 0.6 * i / max(n_views - 1, 1)
        cam = Camera(intrinsics(28.0, 28.0, width / 2, height / 2),
                     look_at([3.0 * np.sin(ang), -3.0 * np.cos(ang), 0.3], [0.0, 0.0, 0.0]),
                     width, height, time=i / max(n_views - 1, 1), name=f"view{i}")
        img = np.zeros((height, width, 3), np.uint8)
        img[:, : width // 2] = (200, 60, 40)
        img[:, width // 2:] = (40, 80, 200)
        img[height // 3: 2 * height // 3] //= 2
        path = root / f"view{i}.png"
        Image.fromarray(img).save(path)
        views.append(_View(cam.name, cam, path))
    points = np.concatenate([rng.normal([-0.4, 0.0, 0.0], 0.2, (150, 3)), rng.normal([0.4, 0.0, 0.0], 0.2, (150, 3))])
    colors = np.concatenate([np.tile([0.8, 0.25, 0.15], (150, 1)), np.tile([0.15, 0.3, 0.8], (150, 1))])
    return views, points, colors


def _masks_for(view):
    """Two masks per view (the image's halves), as a mask generator would give them."""
    from masks.maskset import MaskSet

    h, w = view.camera.height, view.camera.width
    left = np.zeros((h, w), bool)
    left[:, : w // 2] = True
    return MaskSet.from_masks(np.stack([left, ~left]), generator="precompile")


def _run_stages(root: Path) -> None:
    """Every kernel-calling path of the stages, on the tiny scene."""
    import torch

    from trase.features import FeatureConfig, train_features
    from trase.reconstruct import reconstruct
    from trase.reconstruction_presets import reconstruction_preset
    from trase.render_views import evaluate_psnr
    from trase.segment import render_alpha, render_visible

    views, points, colors = _tiny_scene(root)
    for monocular in (True, False):  # the two CPU schedules share kernels; both statistics paths
        cfg = dataclasses.replace(
            reconstruction_preset("cpu", monocular=monocular), iterations=4, warm_up=2, densify_from=1,
            densify_interval=2, densify_until=4, opacity_entropy_from=1, checkpoint_interval=4,
            densify_statistic="lstsq" if monocular else "means2d", deform_visible_only=not monocular,
            device="cpu")  # the numba kernels are the CPU's (on a GPU machine "auto" would pick gsplat)
        gaussians, deform = reconstruct(views, points, colors, cfg, root / f"geometry{int(monocular)}",
                                        resume=False, progress=False)
    evaluate_psnr(gaussians, deform, views)
    for fastpath, threads in ((True, 1), (False, 1), (True, 2), (False, 2)):
        cfg = FeatureConfig.preset("cpu", iterations=2, fastpath=fastpath, torch_threads=threads, device="cpu")
        train_features(gaussians, deform, views, _masks_for, cfg, cache_dir=root / f"features{int(fastpath)}{threads}",
                       progress=False)
    sel = np.zeros(gaussians.num_gaussians, bool)
    sel[: gaussians.num_gaussians // 2] = True
    with torch.no_grad():
        for v in views:
            render_alpha(gaussians, deform, sel, v.camera)
            render_visible(gaussians, deform, sel, v.camera)


def compile_kernels() -> dict:
    """Run the miniature; -> {"seconds", "compiled": [kernel names compiled now]}. Kernels
    already in numba's cache are loaded, not compiled, so a second call compiles none."""
    t0 = time.perf_counter()
    with _CompileCounter() as counter, tempfile.TemporaryDirectory(prefix="trase-precompile-") as tmp:
        _run_stages(Path(tmp))
    return {"seconds": time.perf_counter() - t0, "compiled": sorted(set(counter.compiled))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m trase.precompile", description=__doc__.splitlines()[0])
    parser.add_argument("--quiet", action="store_true", help="print nothing")
    args = parser.parse_args(argv)
    out = compile_kernels()
    if not args.quiet:
        n = len(out["compiled"])
        print(f"trase kernels: {n} compiled in {out['seconds']:.1f} s" if n else
              f"trase kernels: all cached ({out['seconds']:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
