"""The numba projection (numba backend) against the torch reference: values, screen rects and
hand-written gradients, including culled, grazing, zero-quaternion and extreme-scale gaussians."""

from __future__ import annotations

import pytest
import torch

from tests.trase.render.scenes import camera
from trase.camera import Camera, intrinsics, look_at
from trase.render.numba_projection import project_gaussians_numba
from trase.render.projection import project_gaussians


def _scene(n=300, seed=0):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g, dtype=torch.float64) * 0.8
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    scales = torch.exp(torch.randn(n, 3, generator=g, dtype=torch.float64) * 0.5 - 2.5)
    means[:10] *= 8.0  # some behind the camera or far off-screen
    means[10] = torch.tensor([0.0, -2.995, 0.3], dtype=torch.float64)  # grazing the near plane
    quats[11] = 0.0  # zero quaternion: identity rotation
    scales[12] = 1e-8
    scales[13] = 1e3
    return means, quats, scales


def _run(fn, cam, means, quats, scales, seed=1):
    leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales)]
    pr = fn(*leaves, cam)
    g = torch.Generator().manual_seed(seed)
    loss = sum((t * torch.randn(t.shape, generator=g, dtype=t.dtype)).sum() for t in (pr.means2d, pr.conics, pr.depths))
    loss.backward()
    return pr, [t.grad for t in leaves]


@pytest.mark.parametrize("cam", [
    camera(64, 48),
    camera(64, 48, cx=10.0, cy=40.0),  # off-centre principal point
    Camera(K=intrinsics(50.0, 45.0, 30.0, 20.0, skew=0.7), w2c=look_at([0.5, -3.0, 1.0], [0.0, 0.0, 0.0]), width=64, height=48),
])
def test_values_and_gradients_match_reference(cam):
    means, quats, scales = _scene()
    ref, g_ref = _run(project_gaussians, cam, means, quats, scales)
    got, g_got = _run(project_gaussians_numba, cam, means, quats, scales)
    for name in ("means2d", "conics", "depths"):
        a, b = getattr(ref, name).detach(), getattr(got, name).detach()
        assert torch.allclose(a, b, rtol=1e-10, atol=1e-10), name
    assert torch.equal(ref.radii, got.radii) and torch.equal(ref.rects, got.rects)
    assert (ref.radii == 0).any(), "the scene should contain culled gaussians"
    for a, b in zip(g_ref, g_got):
        assert torch.isfinite(b).all()
        assert float((a - b).abs().max()) <= 1e-9 * max(1.0, float(a.abs().max()))


def test_float32_inputs_keep_dtype_and_gradients_flow():
    means, quats, scales = (t.float() for t in _scene(50, seed=2))
    pr, grads = _run(project_gaussians_numba, camera(), means, quats, scales)
    assert pr.means2d.dtype == torch.float32 and pr.conics.dtype == torch.float32
    assert all(g.dtype == torch.float32 and torch.isfinite(g).all() for g in grads)
    assert all(float(g.abs().sum()) > 0 for g in grads)
