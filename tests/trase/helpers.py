"""A tiny two-object dynamic scene with exact masks, for fast feature/segmentation tests."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from masks.maskset import MaskSet
from trase.camera import Camera, intrinsics, look_at
from trase.deformation import TabulatedDeformation
from trase.gaussians import GaussianModel
from trase.render import rasterize


@dataclasses.dataclass
class TinyView:
    name: str
    camera: Camera
    image_path: Path = Path("none")
    frame: int = 0

    @property
    def time(self):
        return self.camera.time


def tiny_scene(n_per=80, seed=0, width=40, height=30, n_views=4):
    """Two blobs of gaussians (ids 0, 1) moving apart over time, cameras around them."""
    g = torch.Generator().manual_seed(seed)
    centres = torch.tensor([[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0]])
    means = torch.cat([c + 0.18 * torch.randn(n_per, 3, generator=g) for c in centres])
    n = means.shape[0]
    ids = np.repeat([0, 1], n_per)
    gm = GaussianModel(
        means,
        torch.full((n, 3), float(np.log(0.07))),
        torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.full((n,), 3.0),
        torch.rand(n, 1, 3, generator=g),
    )
    T = 3
    d = torch.zeros(T, n, 3)
    for k in range(T):
        d[k, : n_per, 0] = -0.1 * k
        d[k, n_per:, 0] = 0.1 * k
    deform = TabulatedDeformation(torch.linspace(0, 1, T), d, torch.zeros(T, n, 4), torch.zeros(T, n, 3))
    views = []
    for i in range(n_views):
        ang = -0.4 + 0.8 * i / max(n_views - 1, 1)
        eye = [3.2 * np.sin(ang), -3.2 * np.cos(ang), 0.4]
        cam = Camera(intrinsics(30, 30, width / 2, height / 2), look_at(eye, [0, 0, 0]), width, height,
                     time=i / max(n_views - 1, 1), name=f"cam/{i:02d}")
        views.append(TinyView(cam.name, cam, frame=i))
    return gm, deform, ids, views


def object_alpha(gm, deform, ids, cam, obj):
    from trase.deformation import deformed

    with torch.no_grad():
        m, q, s = deformed(gm, deform, cam.time)
        sel = torch.from_numpy(ids == obj)
        return rasterize(m[sel], q[sel], s[sel], gm.opacities[sel], cam, features=torch.ones(int(sel.sum()), 1)).alpha.numpy()


def exact_masks(gm, deform, ids, view):
    """Per-object visible masks (alpha >= 0.5, labelled by the dominant object)."""
    from trase.deformation import deformed

    with torch.no_grad():
        m, q, s = deformed(gm, deform, view.camera.time)
        onehot = torch.nn.functional.one_hot(torch.from_numpy(ids).long(), 2).float()
        out = rasterize(m, q, s, gm.opacities, view.camera, features=onehot)
    f = out.features.numpy()
    fg = out.alpha.numpy() >= 0.5
    lab = np.argmax(f, axis=2)
    masks = [fg & (lab == k) for k in range(2)]
    masks = [mk for mk in masks if mk.any()]
    return MaskSet.from_masks(np.stack(masks), generator="exact")
