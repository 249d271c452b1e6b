"""A tiny dynamic scene rendered from known gaussians, for reconstruction tests.

Not a test module (no test_ prefix): shared by test_reconstruct and test_checkpoint.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from trase.camera import Camera, intrinsics, look_at
from trase.deformation import TabulatedDeformation, deformed
from trase.gaussians import GaussianModel, rgb_to_sh_dc


@dataclasses.dataclass(frozen=True)
class TinyView:
    camera: Camera
    image_path: Path


def make_gt(n: int = 200, seed: int = 0, times=(0.0, 0.5, 1.0)):
    """Ground-truth gaussians in a unit ball plus a sideways motion of half of them."""
    rng = np.random.default_rng(seed)
    means = rng.uniform(-0.6, 0.6, (n, 3))
    colors = rng.uniform(0.1, 0.9, (n, 3))
    sh = rgb_to_sh_dc(colors)[:, None, :]
    log_s = np.log(rng.uniform(0.05, 0.12, (n, 3)))
    q = rng.normal(size=(n, 4))
    logits = np.full(n, 2.0)
    t = lambda a: torch.as_tensor(a, dtype=torch.float32)
    g = GaussianModel(t(means), t(log_s), t(q), t(logits), t(sh))
    T = len(times)
    d_xyz = np.zeros((T, n, 3))
    moving = means[:, 0] > 0
    for i, tt in enumerate(times):
        d_xyz[i, moving, 1] = 0.3 * tt
    deform = TabulatedDeformation(np.asarray(times), d_xyz, np.zeros((T, n, 4)), np.zeros((T, n, 3)))
    return g, deform


def make_cameras(num: int = 6, size: int = 32, times=(0.0, 0.5, 1.0)):
    cams = []
    for i in range(num):
        ang = 2 * np.pi * i / num
        eye = np.array([3.0 * np.cos(ang), 3.0 * np.sin(ang), 0.8])
        K = intrinsics(size * 1.2, size * 1.2, size / 2, size / 2)
        cams.append(Camera(K=K, w2c=look_at(eye, np.zeros(3)), width=size, height=size,
                           time=float(times[i % len(times)]), name=f"cam{i}"))
    return cams


def write_scene(root: Path, num: int = 6, size: int = 32, backend: str = "numba", times=(0.0, 0.5, 1.0)):
    """Render the ground truth into PNGs under root; returns (views, points, gt, deform)."""
    import cv2

    from trase.render import rasterize

    root.mkdir(parents=True, exist_ok=True)
    g, deform = make_gt()
    views = []
    for cam in make_cameras(num, size, times):
        with torch.no_grad():
            m, q, s = deformed(g, deform, cam.time)
            out = rasterize(m, q, s, g.opacities, cam, colors=g.sh, sh_degree=0,
                            background=torch.zeros(3), backend=backend)
        img = (out.color.clamp(0, 1).numpy() * 255).round().astype(np.uint8)
        path = root / f"{cam.name}.png"
        cv2.imwrite(str(path), img[:, :, ::-1])
        views.append(TinyView(cam, path))
    pts = g.means.detach().numpy() + np.random.default_rng(1).normal(0, 0.02, (g.num_gaussians, 3))
    return views, pts, g, deform
