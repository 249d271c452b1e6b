"""Render modes, colourings and camera paths of trase.visualize on the tiny scene."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.trase.helpers import tiny_scene
from trase.edit import EditableModel, by_clusters
from trase.visualize import (
    MODES,
    Painter,
    VisualizeError,
    cluster_colours,
    depth_colors,
    feature_pca,
    look_centre,
    orbit_cameras,
)


@pytest.fixture(scope="module")
def model():
    gm, deform, ids, views = tiny_scene()
    g = torch.Generator().manual_seed(0)
    gm.features = torch.nn.Parameter(torch.randn(gm.num_gaussians, 8, generator=g))
    return EditableModel(gm, deform, ids, np.ones(len(ids), bool)), views


def test_every_mode_draws_something(model):
    m, views = model
    painter = Painter(m, by_clusters(m, [1]))
    cam = views[1].camera
    images = {mode: painter.render(cam, mode) for mode in MODES}
    for mode, img in images.items():
        assert img.shape == (cam.height, cam.width, 3) and img.dtype == np.uint8 and img.max() > 0, mode
    assert not np.array_equal(images["rgb"], images["selection"])
    painter.set_selection(None)
    assert np.array_equal(painter.render(cam, "selection"), images["rgb"])  # nothing tinted
    with pytest.raises(VisualizeError, match="unknown render mode"):
        painter.render(cam, "normals")


def test_pca_needs_features_and_devices_are_checked(model):
    m, views = model
    bare = EditableModel(m.gaussians.copy(), m.deformation, m.labels, m.keep)
    bare.gaussians.features = None
    with pytest.raises(VisualizeError, match="needs learned features"):
        Painter(bare).render(views[0].camera, "pca")
    if not torch.cuda.is_available():
        with pytest.raises(VisualizeError, match="sees no GPU"):
            Painter(m, device="cuda")
        assert Painter(m, device="auto").device.type == "cpu"


def test_a_gpu_without_gsplat_is_refused_before_drawing(model, monkeypatch):
    import importlib.util

    m, _ = model
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: None if n == "gsplat" else real(n, *a))
    with pytest.raises(VisualizeError, match=r"draws with gsplat, which is not installed"):
        Painter(m, device="auto")


def test_colourings():
    c = cluster_colours(np.array([0, 1, 0, -1]))
    assert np.array_equal(c[0], c[2]) and not np.array_equal(c[0], c[1]) and np.allclose(c[3], 0.3)
    assert np.array_equal(cluster_colours(np.array([0, 1])), c[:2])  # stable: same id, same colour
    p = feature_pca(np.random.default_rng(0).normal(size=(50, 6)))
    assert p.shape == (50, 3) and p.min() >= 0 and p.max() <= 1
    with pytest.raises(VisualizeError):
        feature_pca(np.zeros((2, 6)))
    depth = np.linspace(1, 2, 12).reshape(3, 4)
    alpha = np.ones((3, 4))
    alpha[0, 0] = 0.0
    img = depth_colors(depth, alpha)
    assert img.shape == (3, 4, 3) and img[0, 0].max() == 0 and img[2, 3].max() > 0
    assert depth_colors(depth, np.zeros((3, 4))).max() == 0


def test_orbit_looks_at_the_centre(model):
    _, views = model
    cams = [v.camera for v in views]
    centre = look_centre(cams)
    assert np.linalg.norm(centre) < 0.05  # the tiny scene's cameras look at the origin
    orbit = orbit_cameras(cams[0], centre, 5, degrees=40)
    assert [c.time for c in orbit] == pytest.approx(np.linspace(0, 1, 5))
    for c in orbit:
        uv, _ = c.project(centre[None])
        assert np.allclose(uv[0], [c.width / 2, c.height / 2], atol=1e-6)
    d = [np.linalg.norm(c.center - centre) for c in orbit]
    assert np.allclose(d, d[0])
    assert np.degrees(np.arccos(np.dot(*(c.center - centre for c in (orbit[0], orbit[-1]))) / d[0] ** 2)) == \
        pytest.approx(40, abs=1e-6)
