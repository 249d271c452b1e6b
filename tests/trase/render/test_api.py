"""Input checks, backend selection, SH conventions."""

import dataclasses

import pytest
import torch

from trase.render import RenderError, rasterize
from trase.render.sh import SH_C0

from .scenes import camera, scene


def test_distorted_camera_is_refused():
    cam = dataclasses.replace(camera(), radial=(0.1, 0.0, 0.0))
    with pytest.raises(RenderError, match="distortion"):
        rasterize(camera=cam, **scene(n=5))


def test_bad_shapes_and_backends_are_refused():
    sc = scene(n=5)
    with pytest.raises(RenderError, match="quats"):
        rasterize(camera=camera(), **{**sc, "quats": torch.zeros(5, 3)})
    with pytest.raises(RenderError, match="SH"):
        rasterize(camera=camera(), **{**sc, "colors": torch.zeros(5, 5, 3)})
    with pytest.raises(RenderError, match="backend"):
        rasterize(camera=camera(), backend="opengl", **sc)
    with pytest.raises(RenderError, match="CUDA"):
        rasterize(camera=camera(), backend="gsplat", **sc)
    assert RenderError.user_facing


def test_sh_degree_zero_is_rgb_and_higher_bands_can_be_ignored():
    cam = camera()
    sc = scene(n=50, d=0, sh_degree=2, seed=3)
    rgb = torch.rand(50, 3)
    sh = sc["colors"].detach().clone()
    sh[:, 0] = (rgb - 0.5) / SH_C0
    base = {k: v for k, v in sc.items() if k not in ("colors", "sh_degree")}
    a = rasterize(camera=cam, backend="numba", colors=rgb, **base)
    b = rasterize(camera=cam, backend="numba", colors=sh, sh_degree=0, **base)
    assert torch.allclose(a.color, b.color, atol=1e-6)
    c = rasterize(camera=cam, backend="numba", colors=sh, **base)  # degree inferred: 2
    assert not torch.allclose(a.color, c.color, atol=1e-3)


def test_auto_backend_is_numba_on_cpu_and_matches():
    cam = camera()
    sc = scene(n=80, seed=11)
    a = rasterize(camera=cam, **sc)
    b = rasterize(camera=cam, backend="numba", **sc)
    assert torch.equal(a.features, b.features)


def test_cpu_import_does_not_touch_gsplat():
    import sys

    rasterize(camera=camera(), **scene(n=5))
    assert "gsplat" not in sys.modules


@pytest.mark.parametrize("backend", ["torch", "numba"])
def test_render_carries_its_projection(backend):
    """means2d and radii are the projection the image was composited from; means2d is in the
    autograd graph, so its gradient is the screen-space gradient 3DGS densifies on."""
    from trase.render.numba_projection import project_gaussians_numba
    from trase.render.projection import project_gaussians

    from .scenes import loss_of

    cam = camera()
    sc = scene(n=60, seed=5, dtype=torch.float64 if backend == "torch" else torch.float32)
    with torch.no_grad():
        sc["means"][:6, 0] += 20.0  # off screen: culled
    out = rasterize(camera=cam, backend=backend, **sc)
    project = project_gaussians if backend == "torch" else project_gaussians_numba
    proj = project(sc["means"], sc["quats"], sc["scales"], cam)
    assert out.means2d.shape == (60, 2) and out.radii.shape == (60,)
    assert torch.equal(out.radii, proj.radii) and torch.allclose(out.means2d, proj.means2d)
    assert (out.radii == 0).any() and (out.radii > 0).any()
    out.means2d.retain_grad()
    loss_of(out).backward()
    g = out.means2d.grad
    assert g is not None and torch.isfinite(g).all()
    assert (g[out.radii == 0] == 0).all() and (g[out.radii > 0].abs().sum(1) > 0).any()
    # it is the gradient with respect to the screen positions: moving one gaussian's 2D
    # position by eps changes the loss by eps * grad (finite difference through the compositor)
    if backend == "torch":
        i = int(torch.nonzero(g.abs().sum(1) > 1e-4)[0])
        from trase.render.torch_backend import composite_torch

        def loss_at(shift):
            m2 = proj.means2d.detach().clone()
            m2[i, 0] += shift
            parts = [sc["colors"], sc["features"], proj.depths[:, None]]
            ch = torch.cat(parts, 1).detach()
            img, alpha = composite_torch(m2, proj.conics.detach(), sc["opacities"].detach(), ch,
                                         proj.depths.detach(), proj.rects, cam.width, cam.height, 16)
            return img, alpha

        # the same linear functional as loss_of, applied to the split outputs
        from trase.render.rasterize import _split

        eps = 1e-6
        lp = loss_of(_split(*loss_at(eps), True, sc["features"].shape[1], None))
        lm = loss_of(_split(*loss_at(-eps), True, sc["features"].shape[1], None))
        assert float((lp - lm) / (2 * eps)) == pytest.approx(float(g[i, 0]), rel=1e-4)


@pytest.mark.parametrize("backend", ["torch", "numba"])
def test_a_render_culls_at_the_cameras_near_plane(backend):
    """A gaussian nearer than the camera's near plane is not drawn; a near named by the caller
    overrides the camera's (the trainer names its own); pixel_weights follows the same plane."""
    from trase.render import pixel_weights

    cam = camera()
    sc = scene(n=1, d=0, seed=2)
    with torch.no_grad():  # 0.1 in front of the camera, on its axis
        sc["means"][0] = torch.tensor(cam.c2w[:3, 3] + 0.1 * cam.c2w[:3, 2], dtype=torch.float32)
        sc["scales"].fill_(0.01)
        sc["opacities"].fill_(0.9)
    near, far = cam, cam.with_near(0.2)
    assert rasterize(camera=near, backend=backend, **sc).alpha.max() > 0.5
    assert rasterize(camera=far, backend=backend, **sc).alpha.max() == 0
    assert rasterize(camera=far, backend=backend, near=0.01, **sc).alpha.max() > 0.5
    geo = [sc[k].detach() for k in ("means", "quats", "scales", "opacities")]
    assert pixel_weights(*geo, near).weights.numel() > 0 and pixel_weights(*geo, far).weights.numel() == 0
