"""Inputs of the feature-step suite: random elliptical masks, the rasterizer suite's random
scene as a GaussianModel, and one view of a cached synthetic scene with its masks."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import torch

N_MASKS = 40


def make_masks(width: int, height: int, n: int = N_MASKS, seed: int = 0):
    """A MaskSet of ``n`` random axis-aligned ellipses (areas from tiny to a third of the image)."""
    from masks.maskset import MaskSet

    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width] + 0.5
    out = np.zeros((n, height, width), bool)
    for i in range(n):
        cx, cy = rng.uniform(0, width), rng.uniform(0, height)
        rx, ry = (rng.uniform(0.03, 0.45, 2) * [width, height])
        out[i] = ((xx - cx) / rx) ** 2 + ((yy - cy) / ry) ** 2 <= 1.0
    return MaskSet.from_masks(out, generator="perf-ellipses")


def make_gaussians(n: int, width: int, height: int):
    """(GaussianModel, Camera) from the rasterizer suite's random scene."""
    from benchmark.perf.raster import make_scene
    from trase.gaussians import GaussianModel, rgb_to_sh_dc

    s, cam = make_scene(n, width, height, 3)
    op = s["opacities"].clamp(1e-4, 1 - 1e-4)
    gm = GaussianModel(s["means"], torch.log(s["scales"]), s["quats"], torch.log(op / (1 - op)),
                       rgb_to_sh_dc(s["colors"]))
    return gm, cam


def synthetic_view(dataset: str, size: str) -> dict:
    """The first training view of the cached synthetic scene with its ground-truth geometry and
    synthetic masks (generated into a temporary folder): the default scene of the speed goal."""
    import masks as masklib
    from benchmark.datasets import get_dataset, load_scene
    from benchmark.datasets.synthetic.cache import ensure_synthetic
    from benchmark.methods.trase_presets import trase_settings
    from masks.generators import make_generator
    from trase.checkpoint import load_tabulated_geometry

    scene_dir = ensure_synthetic(dataset, size=size)
    scene = load_scene(dataset, scene_dir, gt_dir=scene_dir / "gt_masks")
    g, deform, _ = load_tabulated_geometry(scene.truth.geometry_path)
    view = scene.train[0]
    work = Path(tempfile.mkdtemp(prefix="perf-features-"))
    masklib.generate_scene_masks([view], make_generator("synthetic", seed=0), work / "masks", progress=False,
                                 instance_maps={view.name: scene.truth.instance_maps[view.name]})
    ms = masklib.load(masklib.mask_path(work / "masks", view.name))
    return {"name": f"synthetic {dataset} ({size}), view {view.name}, ground-truth geometry",
            "gaussians": g, "deformation": deform, "camera": view.camera, "masks": ms,
            "m_prime": trase_settings("paper", get_dataset(dataset).key).features.n_masks}
