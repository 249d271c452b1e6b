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
