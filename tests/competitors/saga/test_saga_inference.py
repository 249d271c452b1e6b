"""SAGA's click inference on the tiny two-object scene, and a short training run that learns to
tell the objects apart at the small scale and join them at the large one."""

import dataclasses

import numpy as np
from trase_bench_saga.inference import gated, rendered_feature, select_by_query
from trase_bench_saga.objective import gate_from_dict
from trase_bench_saga.settings import SAGA_PRESETS, SagaFeatures
from trase_bench_saga.train import train_saga

from benchmark.protocol.prompts import interior_points
from lazyspecs.presets import Context
from masks.maskset import MaskSet
from tests.trase.helpers import exact_masks, tiny_scene


def test_gated_features_are_unit_and_gates_pick_channels():
    f = np.array([[1.0, 0.0, 1.0], [1.0, 0.0, -1.0]])
    g = gated(f, np.array([1.0, 1.0, 0.0]))
    assert np.allclose(np.linalg.norm(g, axis=1), 1.0)
    assert np.allclose(g[0], g[1])  # the channel that tells them apart is gated off
    sel = select_by_query(f, np.array([1.0, 1.0, 1.0]), [np.array([2.0, 0.0, 2.0])], 0.75)
    assert sel.tolist() == [True, False]
    assert select_by_query(f, np.array([1.0, 1.0, 0.0]), [np.array([2.0, 0.0, 2.0])], 0.75).tolist() == [True, True]
    assert not select_by_query(f, np.ones(3), [], 0.75).any()  # no click on a surface: nothing


def test_a_click_selects_the_object_under_it():
    gm, deform, ids, views = tiny_scene()
    feats = np.eye(2)[ids] + 0.01  # perfect features: one channel per object
    cam = views[1].camera
    for k in range(2):
        (u, v), = interior_points(exact_masks(gm, deform, ids, views[1]).masks[k], 1)[:1]
        q = rendered_feature(gm, deform, cam, u, v, feats)
        assert q is not None and np.argmax(q) == k
        sel = select_by_query(feats, np.ones(2), [q], 0.75)
        assert np.array_equal(sel, ids == k)
    assert rendered_feature(gm, deform, cam, -1.0, 3.0, feats) is None  # off the image
    assert rendered_feature(gm, deform, cam, 0.5, 0.5, feats) is None  # background corner: no alpha


def _nested_masks(gm, deform, ids, view):
    """Each object's mask and one mask of both (the larger scale)."""
    ms = exact_masks(gm, deform, ids, view)
    both = ms.masks.any(axis=0, keepdims=True)
    return MaskSet.from_masks(np.concatenate([ms.masks, both]), generator="exact")


def test_training_separates_objects_at_the_small_scale_only():
    gm, deform, ids, views = tiny_scene()
    cfg = dataclasses.replace(SagaFeatures(), iterations=120, lr=0.05, n_rays=300, norm_pixels="sampled",
                              torch_threads=1, fastpath=True, device="cpu")
    res = train_saga(gm, deform, views, lambda v: _nested_masks(gm, deform, ids, v), cfg)
    feats = res.features.numpy()
    assert res.scale_stats["n_masks"] == 3 * len(views)
    small = gated(feats, gate_from_dict(res.gate, 0.0))
    large = gated(feats, gate_from_dict(res.gate, 1.0))
    c0, c1 = small[ids == 0].mean(0), small[ids == 1].mean(0)
    cross_small = float(c0 @ c1 / np.linalg.norm(c0) / np.linalg.norm(c1))
    l0, l1 = large[ids == 0].mean(0), large[ids == 1].mean(0)
    cross_large = float(l0 @ l1 / np.linalg.norm(l0) / np.linalg.norm(l1))
    assert cross_small < 0.5 < cross_large, (cross_small, cross_large)
    assert res.history and np.isfinite(res.history[-1]["loss"])


def test_presets_paper_are_the_public_defaults_and_cpu_is_smaller():
    paper = SAGA_PRESETS.resolve("paper", Context(dataset="hypernerf")).config
    assert (paper.features.dim, paper.features.iterations, paper.features.lr, paper.features.n_rays) == (32, 10000, 0.0025, 1000)
    assert (paper.inference.scale, paper.inference.threshold) == (0.5, 0.75)
    assert (cpu_inf := SAGA_PRESETS.resolve("cpu", Context(dataset="nerfds")).config.inference).scale == 0.75
    assert cpu_inf.threshold == 0.65
    cpu = SAGA_PRESETS.resolve("cpu", Context(dataset="hypernerf")).config
    assert cpu.features.iterations < paper.features.iterations and cpu.render_rule == "visible"
    assert SAGA_PRESETS.resolve("cpu", Context(dataset="neu3d", monocular=False)).config.render_rule == "alone"


def test_a_clustering_parameter_no_algorithm_reads_is_refused_before_any_stage():
    import pytest
    from trase_bench_saga.method import SagaMethod

    from benchmark.config import ConfigError

    cfg = SAGA_PRESETS.resolve("cpu", Context(dataset="hypernerf")).config
    SagaMethod().check_settings(cfg)
    cfg.clustering.params = {**cfg.clustering.params, "cluster_selection_method": "leaf"}
    with pytest.raises(ConfigError, match="method.clustering: clustering parameter 'cluster_selection_method'"):
        SagaMethod().check_settings(cfg)


def test_mask_scales_come_from_rendered_depth():
    from trase_bench_saga.train import view_scales

    gm, deform, ids, views = tiny_scene()
    ms = _nested_masks(gm, deform, ids, views[0])
    s = view_scales(gm, deform, views[0].camera, ms, erode_min=5, min_alpha=0.5)
    # each blob spans ~0.4 m (0.18 std per axis, seen from one side); both together ~1.2 m apart
    assert 0.1 < s[0] < 0.8 and 0.1 < s[1] < 0.8 and s[2] > 1.5 * max(s[0], s[1])
