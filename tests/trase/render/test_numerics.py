"""Degenerate but legal inputs give finite outputs and gradients, and the backends agree."""

import math

import numpy as np
import pytest
import torch

from trase.render import rasterize

from .scenes import camera, grads, loss_of


def _gaussians(means, scales, opacities, quats=None):
    n = len(means)
    g = torch.Generator().manual_seed(0)
    return {
        "means": torch.tensor(means, dtype=torch.float32).requires_grad_(True),
        "quats": (torch.tensor(quats, dtype=torch.float32) if quats is not None else torch.randn(n, 4, generator=g)).requires_grad_(True),
        "scales": torch.tensor(scales, dtype=torch.float32).requires_grad_(True),
        "opacities": torch.tensor(opacities, dtype=torch.float32).requires_grad_(True),
        "colors": torch.rand(n, 3, generator=g).requires_grad_(True),
        "features": torch.randn(n, 4, generator=g).requires_grad_(True),
    }


# camera at (0, -3, 0.3) looking at the origin; camera z ~ world y + 3
CASES = {
    "behind": ([[0.0, -4.0, 0.3], [0.0, -3.0, 0.3], [0.0, 0.0, 0.0]], [[0.3] * 3] * 3, [0.9, 0.9, 0.5]),
    "grazing": ([[0.0, -2.995, 0.3], [5.0, -2.98, 0.3], [0.1, -2.0, 0.2]], [[0.05] * 3] * 3, [0.9, 0.9, 0.5]),
    "tiny_scale": ([[0.0, 0.0, 0.0], [0.1, 0.0, 0.1]], [[1e-8] * 3, [1e-8, 1.0, 1e-8]], [0.9, 0.9]),
    "huge_scale": ([[0.0, 0.0, 0.0], [0.2, 1.0, 0.0]], [[1e4] * 3, [1e4, 1e-3, 1e4]], [0.5, 0.9]),
    "opacity_0_and_1": ([[0.0, 0.0, 0.0], [0.1, 0.5, 0.0]], [[0.2] * 3] * 2, [0.0, 1.0]),
    "offscreen_and_border": (
        [[50.0, 0.0, 0.0], [0.0, 0.0, -50.0], [1.48, 0.0, 0.0], [-1.5, 0.0, 1.2]],
        [[0.1] * 3] * 4,
        [0.9] * 4,
    ),
    "zero_quaternion": ([[0.0, 0.0, 0.0]], [[0.2, 0.1, 0.05]], [0.9], [[0.0, 0.0, 0.0, 0.0]]),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_finite_and_backends_agree(case):
    cam = camera()
    results = {}
    for backend in ("torch", "numba"):
        sc = _gaussians(*CASES[case])
        out = rasterize(camera=cam, backend=backend, **sc)
        for name in ("color", "features", "depth", "alpha"):
            assert torch.isfinite(getattr(out, name)).all(), (backend, name)
        loss_of(out).backward()
        g = grads(sc)
        for name, v in g.items():
            assert torch.isfinite(v).all(), (backend, name)
        results[backend] = (out, g)
    (ot, gt), (on, gn) = results["torch"], results["numba"]
    assert torch.allclose(ot.color, on.color, atol=1e-4)
    assert torch.allclose(ot.alpha, on.alpha, atol=1e-4)
    for name in gt:
        assert (gt[name] - gn[name]).abs().max() <= 1e-3 * max(gt[name].abs().max(), 1e-6), name


def test_behind_camera_is_culled():
    cam = camera()
    sc = _gaussians([[0.0, -4.0, 0.3]], [[0.5] * 3], [1.0])
    out = rasterize(camera=cam, backend="numba", **sc)
    assert out.alpha.abs().max() == 0


def test_opaque_layers_stop_at_transmittance_floor():
    """Many opaque gaussians on the axis: alpha stops just short of 1 (T >= 1e-4 rule)."""
    cam = camera()
    n = 12
    sc = _gaussians([[0.0, 0.1 * i, 0.3] for i in range(n)], [[0.5] * 3] * n, [1.0] * n)
    for backend in ("torch", "numba"):
        out = rasterize(camera=cam, backend=backend, **sc)
        a = out.alpha[16, 20].item()
        assert 1e-4 * 0.999 <= 1 - a < 1e-3  # opaque, but T never drops below the floor


def test_off_centre_principal_point_and_depth():
    """A small opaque gaussian renders its peak where Camera.project puts it, with its depth."""
    cam = camera(width=50, height=40, cx=13.0, cy=29.0)
    p = np.array([[0.1, 0.2, -0.1]])
    uv, z = cam.project(p)
    sc = _gaussians(p.tolist(), [[0.03] * 3], [0.9], quats=[[1.0, 0.0, 0.0, 0.0]])
    for backend in ("torch", "numba"):
        out = rasterize(camera=cam, backend=backend, **sc)
        a = out.alpha.detach()
        yy, xx = torch.meshgrid(torch.arange(40) + 0.5, torch.arange(50) + 0.5, indexing="ij")
        cu = (a * xx).sum() / a.sum()
        cv = (a * yy).sum() / a.sum()
        assert abs(cu - uv[0, 0]) < 0.05 and abs(cv - uv[0, 1]) < 0.05
        j, i = int(uv[0, 1]), int(uv[0, 0])
        assert math.isclose(out.depth[j, i].item(), z[0], rel_tol=1e-5)
        assert out.depth[0, 0] == 0  # empty pixels have depth 0


@pytest.mark.parametrize("backend", ["torch", "numba"])
def test_empty_and_fully_culled_scenes_still_backpropagate(backend):
    for n, z in ((0, 0.0), (3, -4.0)):
        sc = _gaussians([[0.0, z, 0.0]] * n, [[0.1] * 3] * n, [0.5] * n) if n else {
            k: torch.zeros(shape, requires_grad=True)
            for k, shape in (("means", (0, 3)), ("quats", (0, 4)), ("scales", (0, 3)), ("opacities", (0,)),
                             ("colors", (0, 3)), ("features", (0, 4)))
        }
        out = rasterize(camera=camera(), backend=backend, **sc)
        assert out.alpha.abs().max() == 0 and out.depth.abs().max() == 0
        loss_of(out).backward()
        assert all(torch.all(g == 0) for g in grads(sc).values())
