"""Gaussians the training views barely see take their seen neighbours' features."""

import numpy as np
import pytest
import torch

from tests.trase.helpers import tiny_scene
from trase.prompts import geometry_at
from trase.render import rasterize
from trase.unseen import neighbours_features, training_weights


def _weights_by_autograd(gm, deform, cams):
    """The reference: d(sum of a rendered zero feature)/d(feature_i) = sum over pixels of w_i."""
    total = np.zeros(gm.num_gaussians)
    for cam in cams:
        with torch.no_grad():
            m, q, s, o = geometry_at(gm, deform, cam.time)
        f = torch.zeros(m.shape[0], 1, dtype=m.dtype, requires_grad=True)
        rasterize(m, q, s, o, cam, features=f).features.sum().backward()
        total += f.grad[:, 0].double().numpy()
    return total


def test_training_weights_are_each_gaussians_compositing_weights_summed_over_the_images():
    gm, deform, _, views = tiny_scene()
    cams = [v.camera for v in views]
    got = training_weights(gm, deform, cams)
    assert got.shape == (gm.num_gaussians,) and np.all(got >= 0) and got.max() > 1
    np.testing.assert_allclose(got, _weights_by_autograd(gm, deform, cams), rtol=1e-4, atol=1e-4)
    assert training_weights(gm, deform, []).sum() == 0


def test_an_unseen_gaussian_takes_the_mean_of_its_nearest_seen_neighbours_at_its_own_norm():
    means = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [10, 0, 0], [1.2, 0, 0]])
    feats = np.array([[1.0, 0], [0, 2], [1, 1], [0, 5], [3, 4]], np.float32)
    seen = np.array([True, True, True, True, False])
    out = neighbours_features(feats, means, seen, k=2)  # nearest seen: 1 and 2
    want = (np.array([0, 1.0]) + np.array([1, 1]) / np.sqrt(2)) / 2 * 5.0
    np.testing.assert_allclose(out[4], want, rtol=1e-6)
    np.testing.assert_array_equal(out[:4], feats[:4])
    np.testing.assert_array_equal(neighbours_features(feats, means, np.ones(5, bool), 2), feats)  # none unseen
    np.testing.assert_array_equal(neighbours_features(feats, means, seen, 5), feats)  # fewer seen than k
    assert np.isfinite(neighbours_features(np.zeros((5, 2), np.float32), means, seen, 1)).all()


def test_the_method_gives_unseen_gaussians_their_neighbours_features_only_when_asked():
    from benchmark.methods.trase_method import TraseMethod
    from benchmark.methods.trase_presets import TraseSettings

    gm, deform, _, views = tiny_scene()
    scene = type("S", (), {"train": views[:1]})()
    rng = np.random.default_rng(0)
    feats = rng.normal(size=(gm.num_gaussians, 8)).astype(np.float32)
    method, off = TraseMethod(), TraseSettings()
    assert method.group_inputs(scene, gm, deform, off) == {}
    on = TraseSettings(unseen_min_weight=0.5, unseen_neighbours=4)
    inputs = method.group_inputs(scene, gm, deform, on)
    unseen = int((inputs["training_weights"] < 0.5).sum())
    assert 0 < unseen < gm.num_gaussians
    fitted = method.group(feats, on, gm, deform, inputs)
    assert fitted.stats["unseen_gaussians"] == unseen
    assert "unseen_gaussians" not in method.group(feats, off, gm, deform, {}).stats


@pytest.mark.parametrize("bad", [{"unseen_min_weight": -1.0}, {"unseen_neighbours": 0}])
def test_bad_unseen_settings_are_refused(bad):
    from benchmark.config import ConfigError
    from benchmark.methods.trase_method import TraseMethod
    from benchmark.methods.trase_presets import TraseSettings

    with pytest.raises(ConfigError, match="method.unseen_"):
        TraseMethod().check_settings(TraseSettings(**bad))
