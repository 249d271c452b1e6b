"""The torch reference's autograd against finite differences, on tiny float64 scenes."""

import torch

from trase.render import rasterize

from .scenes import camera, loss_of, scene


def _gradcheck(sc, cam, names):
    fixed = {k: (v.detach() if torch.is_tensor(v) else v) for k, v in sc.items()}

    def f(*xs):
        kw = dict(fixed)
        kw.update(dict(zip(names, xs)))
        return loss_of(rasterize(camera=cam, backend="torch", **kw))

    inputs = tuple(sc[k].detach().clone().requires_grad_(True) for k in names)
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-3, fast_mode=True)


def test_reference_gradients_match_finite_differences():
    cam = camera(width=14, height=11, f=14.0, cx=6.2, cy=5.9)
    sc = scene(n=6, d=2, seed=5, dtype=torch.float64, spread=0.4, log_scale=-1.3)
    with torch.no_grad():
        sc["opacities"].clamp_(0.1, 0.8)  # keep away from the 0.99 alpha clamp
    _gradcheck(sc, cam, ["means", "quats", "scales", "opacities", "colors", "features"])


def test_reference_sh_gradients_match_finite_differences():
    cam = camera(width=12, height=10, f=12.0)
    sc = scene(n=4, d=0, sh_degree=2, seed=6, dtype=torch.float64, spread=0.3, log_scale=-1.2)
    with torch.no_grad():
        sc["opacities"].clamp_(0.1, 0.8)
    _gradcheck(sc, cam, ["means", "colors"])
