"""The gsplat adapter on the CPU: a stand-in for ``gsplat.rasterization`` built on the torch
reference (same projection and compositing, gsplat's calling conventions and output layout)
must give back exactly what the torch backend gives, including the screen-space gradient the
trainer densifies on. What gsplat's own kernels do is checked on a GPU (test_cuda_backends)."""

import sys
import types

import pytest
import torch

from trase.render import rasterize
from trase.render.gsplat_backend import rasterize_gsplat
from trase.render.projection import project_gaussians
from trase.render.torch_backend import composite_torch

from .scenes import camera, grads, loss_of, scene


def _stand_in(means, quats, scales, opacities, colors, viewmats, Ks, width, height, near_plane,
              sh_degree, render_mode, packed):
    """gsplat.rasterization's contract for one camera: image [1, H, W, C + 1] (channels, then
    expected depth), alpha [1, H, W, 1], meta with means2d [1, N, 2] in the graph and radii [1, N, 2].
    With ``sh_degree``, ``colors`` are SH coefficients [N, K, 3] evaluated toward the camera
    centre (gsplat takes it from the inverse view matrix) plus 0.5, clamped at 0."""
    assert render_mode == "RGB+ED" and not packed
    assert viewmats.shape == (1, 4, 4) and Ks.shape == (1, 3, 3)
    from trase.camera import Camera
    from trase.render.sh import eval_sh

    if sh_degree is not None:
        assert colors.ndim == 3 and (sh_degree + 1) ** 2 <= colors.shape[1]
        campos = torch.inverse(viewmats)[0, :3, 3]
        dirs = torch.nn.functional.normalize(means - campos, dim=1)
        colors = (eval_sh(sh_degree, colors, dirs) + 0.5).clamp_min(0.0)

    cam = Camera(K=Ks[0].detach().double().numpy(), w2c=viewmats[0].detach().double().numpy(),
                 width=width, height=height)
    proj = project_gaussians(means, quats, scales, cam, near=near_plane, dtype=means.dtype)
    means2d = proj.means2d[None]  # [1, N, 2]: what the image is computed from
    chans = torch.cat([colors, proj.depths[:, None]], dim=1)
    out, alpha = composite_torch(means2d[0], proj.conics, opacities, chans, proj.depths, proj.rects,
                                 width, height, 16)
    has = alpha > 1e-6
    depth = torch.where(has, out[..., -1] / torch.where(has, alpha, torch.ones_like(alpha)),
                        torch.zeros_like(alpha))
    img = torch.cat([out[..., :-1], depth[..., None]], dim=-1)
    radii = proj.radii[None, :, None].expand(1, -1, 2).to(torch.int32)
    return img[None], alpha[None, ..., None], {"means2d": means2d, "radii": radii}


@pytest.fixture()
def fake_gsplat(monkeypatch):
    monkeypatch.setitem(sys.modules, "gsplat", types.SimpleNamespace(rasterization=_stand_in))


@pytest.mark.parametrize("kw", [{"n": 120, "d": 4, "seed": 0}, {"n": 90, "d": 0, "sh_degree": 2, "seed": 1},
                                {"n": 60, "d": 6, "seed": 2, "sh_degree": None},
                                {"n": 80, "d": 0, "sh_degree": 3, "seed": 3},
                                {"n": 70, "d": 2, "sh_degree": 1, "seed": 4}])
def test_adapter_returns_what_the_reference_returns(fake_gsplat, kw):
    cam = camera()
    bg = torch.tensor([0.1, 0.4, 0.8])
    ref_sc, ada_sc = scene(**kw), scene(**kw)
    ref = rasterize(camera=cam, backend="torch", background=bg, **ref_sc)
    ada = rasterize_gsplat(ada_sc["means"], ada_sc["quats"], ada_sc["scales"], ada_sc["opacities"], cam,
                           ada_sc["colors"], ada_sc.get("sh_degree"), ada_sc.get("features"), bg, 0.01)
    for name in ("color", "features", "depth", "alpha"):
        a, b = getattr(ref, name), getattr(ada, name)
        assert (a is None) == (b is None), name
        if a is not None:
            assert torch.allclose(a, b, atol=1e-6), name
    assert torch.equal(ada.radii, ref.radii) and ada.radii.dtype == torch.int64
    ref.means2d.retain_grad()
    ada.means2d.retain_grad()
    loss_of(ref).backward()
    loss_of(ada).backward()
    assert ada.means2d.shape == ref.means2d.shape
    assert ada.means2d.grad is not None, "the screen-space gradient must reach RenderOutput.means2d"
    assert (ada.means2d.grad - ref.means2d.grad).abs().max() <= 1e-5 * ref.means2d.grad.abs().max()
    g_ref, g_ada = grads(ref_sc), grads(ada_sc)
    assert set(g_ref) == set(g_ada)
    for k in g_ref:
        assert (g_ref[k] - g_ada[k]).abs().max() <= 1e-5 * g_ref[k].abs().max(), k


def test_colour_only_sh_is_evaluated_by_gsplat(monkeypatch):
    """A colour-only render hands the SH coefficients to gsplat (its fused kernel); with
    features beside the colour they are evaluated here and passed as plain channels."""
    seen = []

    def spy(*args, **kw):
        seen.append((kw["sh_degree"], args[4].ndim))
        return _stand_in(*args, **kw)

    monkeypatch.setitem(sys.modules, "gsplat", types.SimpleNamespace(rasterization=spy))
    cam = camera()
    for d in (0, 3):
        sc = scene(n=40, d=d, sh_degree=2, seed=5)
        rasterize_gsplat(sc["means"], sc["quats"], sc["scales"], sc["opacities"], cam, sc["colors"], 2,
                         sc.get("features"), None, 0.01)
    assert seen == [(2, 3), (None, 2)]


def test_features_only_and_no_gradient(fake_gsplat):
    cam = camera()
    sc = {k: (v.detach() if torch.is_tensor(v) else v) for k, v in scene(n=50, d=3, seed=4).items()}
    out = rasterize_gsplat(sc["means"], sc["quats"], sc["scales"], sc["opacities"], cam, None, None,
                           sc["features"], None, 0.01)
    ref = rasterize(camera=cam, backend="torch", **{**sc, "colors": None})
    assert out.color is None and torch.allclose(out.features, ref.features, atol=1e-6)
    assert not out.means2d.requires_grad
