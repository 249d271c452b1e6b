"""OpenGaussian trains separating features once the loop supplies the rendered alpha.

``trase.features.train_features`` does not fill ``PixelSample.alpha``; this test runs the same
steps by hand with alpha rendered through the frozen-geometry path (features of ones), which is
what the loop needs to do for objectives with ``needs_alpha``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.opengaussian import OpenGaussianObjective
from tests.trase.helpers import exact_masks, tiny_scene
from trase.fastpath import ViewWeights
from trase.features import build_sample, init_features


@pytest.mark.slow
def test_opengaussian_separates_objects_with_rendered_alpha(tmp_path):
    gm, deform, ids, views = tiny_scene()
    masks = [exact_masks(gm, deform, ids, v) for v in views]
    path = ViewWeights(gm, deform, tmp_path)
    for i, (v, ms) in enumerate(zip(views, masks)):
        path.register(i, v.name, v.camera, ms.covered)
    rng = np.random.default_rng(0)
    gen = torch.Generator().manual_seed(0)
    feats = torch.nn.Parameter(init_features(gm.num_gaussians, 6, gen))
    opt = torch.optim.Adam([feats], lr=0.02, eps=1e-15)
    obj = OpenGaussianObjective()
    assert obj.needs_alpha
    ones = torch.ones(gm.num_gaussians, 1)
    for _ in range(60):
        vi = int(rng.integers(len(views)))
        sample = build_sample(masks[vi], "random", 3, 300, rng, view=vi)
        sample.alpha = path.render(vi, ones, sample.pixels)[:, 0]
        f = torch.nn.functional.normalize(feats, dim=1)  # OpenGaussian normalises per gaussian
        loss, stats = obj(path.render(vi, f, sample.pixels), sample)
        opt.zero_grad()
        loss.backward()
        opt.step()
        assert torch.isfinite(loss) and stats["n_masks"] >= 1
    f = torch.nn.functional.normalize(feats.detach(), dim=1)
    means = torch.stack([f[ids == 0].mean(0), f[ids == 1].mean(0)])
    assert float(torch.nn.functional.cosine_similarity(means[0], means[1], dim=0)) < 0.0
    nearest = torch.cdist(f, means).argmin(dim=1).numpy()
    assert (nearest == ids).mean() > 0.9  # each gaussian is nearer its own object's mean
