"""A fixed seed gives the same bits whatever the number of numba threads (the rasterizer's and
the fast path's parallel loops): reconstruction and feature training compared under 1 and 2
threads. Torch's own intra-op threads are part of the config (``torch_threads``): they change
the reduction order, so they are recorded with every result rather than free."""

import sys
from pathlib import Path

import numba
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))

from recon_scene import write_scene

from tests.trase.helpers import exact_masks, tiny_scene
from trase.features import FeatureConfig, train_features
from trase.reconstruct import reconstruct
from trase.reconstruction_presets import reconstruction_preset

pytestmark = pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 numba threads")


def _under(threads: int, fn):
    old = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        return fn()
    finally:
        numba.set_num_threads(old)


def test_reconstruction_is_bit_identical_under_1_and_2_numba_threads(tmp_path):
    views, pts, _, _ = write_scene(tmp_path / "images", num=6, size=24)
    cfg = reconstruction_preset("cpu", iterations=30, warm_up=10, densify_from=5, densify_until=25, densify_interval=10,
                                   checkpoint_interval=30, time_noise_steps=30, torch_threads=1)
    a, da = _under(1, lambda: reconstruct(views, pts, None, cfg, tmp_path / "one", progress=False))
    b, db = _under(2, lambda: reconstruct(views, pts, None, cfg, tmp_path / "two", progress=False))
    for name in ("means", "log_scales", "quats", "opacity_logits", "sh_dc"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
    for (k, x), (_, y) in zip(da.state_dict().items(), db.state_dict().items()):
        assert torch.equal(x, y), k


def test_feature_training_is_bit_identical_under_1_and_2_numba_threads(tmp_path):
    gm, deform, ids, views = tiny_scene()
    masks = {v.name: exact_masks(gm, deform, ids, v) for v in views}
    cfg = FeatureConfig(dim=8, iterations=40, n_pixels=300, n_masks=3, knn=4, knn_keep=2, lr=0.05, fastpath=True,
                        torch_threads=1)

    def train(sub):
        return train_features(gm, deform, views, lambda v: masks[v.name], cfg, cache_dir=tmp_path / sub,
                              progress=False).features

    assert torch.equal(_under(1, lambda: train("one")), _under(2, lambda: train("two")))
