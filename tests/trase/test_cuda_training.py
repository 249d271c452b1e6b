"""Reconstruction and feature training on a GPU (``device="cuda"``), with the torch and the
gsplat rasterizers: they run, learn, write checkpoints the CPU reads, resume, and the feature
fast path on the GPU starts where the CPU's does. Skipped without CUDA (gsplat cases without
gsplat)."""

import dataclasses

import numpy as np
import pytest
import torch

from tests.trase.helpers import exact_masks, tiny_scene
from tests.trase.recon_scene import write_scene
from trase.checkpoint import load_model
from trase.features import FeatureConfig, train_features
from trase.gaussians import GaussianModel
from trase.reconstruct import reconstruct
from trase.reconstruction_presets import reconstruction_preset
from trase.render_views import evaluate_psnr

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")

CFG = reconstruction_preset(
    "cpu",     iterations=40, warm_up=15, densify_from=10, densify_until=35, densify_interval=10,
    checkpoint_interval=20, time_noise_steps=40, position_lr_max_steps=40, deform_lr_max_steps=40,
    device="cuda",
)


def _backend(name):
    if name == "gsplat":
        pytest.importorskip("gsplat")
    return name


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny")
    views, pts, _, _ = write_scene(root / "images", num=6, size=24, backend="torch")
    return views, pts


@pytest.mark.parametrize("backend", ["torch", "gsplat"])
@pytest.mark.parametrize("statistic", ["lstsq", "means2d"])
def test_reconstruction_on_cuda_learns_and_its_checkpoint_loads_on_cpu(scene, tmp_path, backend, statistic):
    backend = _backend(backend)
    views, pts = scene
    cfg = dataclasses.replace(CFG, densify_statistic=statistic)
    init = GaussianModel.from_points(pts, None, sh_degree=1)
    p0 = evaluate_psnr(init, None, views, backend="torch")
    g, d = reconstruct(views, pts, None, cfg, tmp_path / "m", progress=False, backend=backend)
    assert g.means.device.type == "cuda"
    p1 = evaluate_psnr(g, d, views, backend=backend)
    assert p1 > p0 + 1.0, (p0, p1)
    g_cpu, d_cpu = load_model(tmp_path / "m")
    assert g_cpu.means.device.type == "cpu" and g_cpu.num_gaussians == g.num_gaussians
    p_cpu = evaluate_psnr(g_cpu, d_cpu, views, backend="torch")
    assert abs(p_cpu - p1) < (1e-3 if backend == "torch" else 0.5), (p_cpu, p1)
    # resumed on the GPU from its own checkpoint
    g2, _ = reconstruct(views, pts, None, dataclasses.replace(cfg, iterations=60), tmp_path / "m",
                        progress=False, backend=backend)
    assert g2.means.device.type == "cuda"


def _features(tmp_path, **kw):
    gm, deform, ids, views = tiny_scene()
    masks = {v.name: exact_masks(gm, deform, ids, v) for v in views}
    cfg = FeatureConfig(dim=8, iterations=120, n_pixels=300, n_masks=3, knn=4, knn_keep=2, lr=0.02, **kw)
    res = train_features(gm, deform, views, lambda v: masks[v.name], cfg, cache_dir=tmp_path, progress=False)
    assert gm.means.device.type == "cpu"  # the caller's geometry stays where it was
    return res, ids


@pytest.mark.parametrize("fastpath, backend", [(True, "auto"), (False, "torch"), (False, "gsplat")])
def test_features_train_on_cuda_and_separate_objects(tmp_path, fastpath, backend):
    if backend == "gsplat":
        _backend(backend)
    res, ids = _features(tmp_path, device="cuda", fastpath=fastpath, render_backend=backend)
    assert res.features.device.type == "cpu" and np.isfinite(res.features.numpy()).all()
    f = torch.nn.functional.normalize(res.features, dim=1)
    a, b = f[ids == 0], f[ids == 1]
    assert (a @ b.T).mean() < 0.3 < (a @ a.T).mean()


def test_feature_fast_path_on_cuda_matches_the_cpu_run(tmp_path):
    cpu, _ = _features(tmp_path / "cpu", device="cpu", fastpath=True)
    gpu, _ = _features(tmp_path / "gpu", device="cuda", fastpath=True)
    assert abs(cpu.history[0]["loss"] - gpu.history[0]["loss"]) < 1e-4
    assert (cpu.features - gpu.features).abs().max() < 5e-2
