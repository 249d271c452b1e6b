import math

import pytest
import torch

from trase.losses import dssim_l1_loss, l1_loss, psnr, ssim, ssim_reference


def test_ssim_identity_and_range():
    a = torch.rand(24, 31, 3, generator=torch.Generator().manual_seed(0))
    assert math.isclose(float(ssim(a, a)), 1.0, abs_tol=1e-5)
    b = torch.rand(24, 31, 3, generator=torch.Generator().manual_seed(1))
    assert float(ssim(a, b)) < 0.2


def test_separable_ssim_equals_2d_window():
    g = torch.Generator().manual_seed(2)
    a, b = torch.rand(2, 20, 17, 3, generator=g), torch.rand(2, 20, 17, 3, generator=g)
    assert torch.allclose(ssim(a, b), ssim_reference(a, b), atol=1e-6)


def test_ssim_gradcheck():
    g = torch.Generator().manual_seed(3)
    a = torch.rand(12, 13, 2, dtype=torch.float64, generator=g, requires_grad=True)
    b = torch.rand(12, 13, 2, dtype=torch.float64, generator=g)
    assert torch.autograd.gradcheck(lambda x: ssim(x, b), (a,))


def test_l1_psnr_and_shape_errors():
    a = torch.zeros(4, 4, 3)
    b = torch.full((4, 4, 3), 0.1)
    assert math.isclose(float(l1_loss(a, b)), 0.1, rel_tol=1e-6)
    assert math.isclose(psnr(a, b), 20.0, rel_tol=1e-5)
    assert psnr(a, a) == math.inf
    assert float(dssim_l1_loss(a, a)) == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ValueError, match="shape"):
        l1_loss(a, torch.zeros(4, 5, 3))


def test_opacity_entropy_is_zero_at_binary_opacities_and_pushes_towards_them():
    from trase.losses import opacity_entropy

    assert float(opacity_entropy(torch.tensor([0.0, 1.0, 1.0]))) == pytest.approx(0.0, abs=1e-4)
    assert float(opacity_entropy(torch.tensor([0.5]))) == pytest.approx(math.log(2), rel=1e-6)
    x = torch.tensor([-1.0, 0.5, 2.0], requires_grad=True)  # logits
    opacity_entropy(torch.sigmoid(x)).backward()
    # descent moves each logit away from 0: opacities towards the nearer of 0 and 1
    assert x.grad[0] > 0 and x.grad[1] < 0 and x.grad[2] < 0
    assert torch.isfinite(x.grad).all()
