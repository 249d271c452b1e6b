"""Densification: the screen-space gradient statistics and the capped densify-and-prune step."""

import numpy as np
import pytest
import torch

from trase.camera import Camera, intrinsics, look_at
from trase.deformation import DeformMLP
from trase.densify import densify_and_prune, lstsq_screen_grad_norm, screen_grad_norm
from trase.gaussians import GaussianModel
from trase.reconstruction_config import ReconstructionConfig


def test_screen_grad_norm_recovers_pixel_gradient():
    cam = Camera(K=intrinsics(100, 90, 50, 40), w2c=look_at(np.array([0.3, -3, 0.5]), np.zeros(3)), width=100, height=80)
    g = torch.Generator().manual_seed(0)
    m = torch.randn(6, 3, dtype=torch.float64, generator=g) * 0.5
    m[5] = torch.as_tensor(cam.center) + torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)  # behind the camera
    w = torch.randn(6, 2, dtype=torch.float64, generator=g)  # loss = sum w . uv  ->  dL/duv = w
    mm = m.clone().requires_grad_()
    R, t = torch.as_tensor(cam.w2c[:3, :3]), torch.as_tensor(cam.w2c[:3, 3])
    p = mm @ R.T + t
    uv = torch.stack([100 * p[:, 0] / p[:, 2] + 50, 90 * p[:, 1] / p[:, 2] + 40], 1)
    (uv * w).sum().backward()
    got = lstsq_screen_grad_norm(mm.grad, m, cam)
    want = (w * torch.tensor([50.0, 40.0], dtype=torch.float64)).norm(dim=1).float()  # NDC units
    assert torch.allclose(got[:5], want[:5], rtol=1e-4)
    assert got[5] == 0


def _densify_points_under_cap(cap: int) -> tuple[GaussianModel, np.ndarray]:
    """200 gaussians, gradients rising with the row (row 0 below the threshold), densified once
    under ``cap``."""
    from trase.reconstruct import _make_optimizers

    pts = np.random.default_rng(0).uniform(-1, 1, (200, 3))
    g = GaussianModel.from_points(pts, None, sh_degree=0)
    cfg = ReconstructionConfig.cpu(max_gaussians=cap, min_opacity=0.0)
    opt, _ = _make_optimizers(g, DeformMLP.preset("small"), cfg)
    grads = torch.linspace(0.0, 1.0, 200)
    grads[0] = 0.0  # 199 candidates above the 0.0004 threshold
    densify_and_prune(g, opt, cfg, grads, torch.ones(200), 1.0, False, torch.Generator().manual_seed(0))
    return g, pts


def test_densification_never_exceeds_the_gaussian_cap_and_keeps_the_largest_gradients():
    # the cpu preset's 15k cap decides a step's cost; densification must respect it exactly
    g, pts = _densify_points_under_cap(230)
    assert g.num_gaussians == 230  # 30 room left: 30 of 199 candidates densified
    # these gaussians are larger than percent_dense x extent, so a densified one is split
    # (its row removed): the first 170 rows stay in place only if the 30 largest-gradient
    # gaussians (the last rows) were the ones chosen
    assert torch.equal(g.means[:170], torch.as_tensor(pts[:170], dtype=g.means.dtype))
    full, _ = _densify_points_under_cap(200)
    assert full.num_gaussians == 200  # at the cap: nothing added


def test_screen_grad_norm_is_ndc_units_of_the_pixel_gradient():
    cam = Camera(K=intrinsics(50, 50, 50, 40), w2c=np.eye(4), width=100, height=80)
    g = torch.tensor([[1.0, 0.0], [0.0, 2.0], [3.0, 4.0], [float("nan"), 0.0]])
    assert screen_grad_norm(g, cam).tolist() == pytest.approx([50.0, 80.0, float(np.hypot(150, 160)), 0.0])
