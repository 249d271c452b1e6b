"""Property-based stress tests of smoothing, clustering and scoring.

* smoothing (trase.smoothing): K nearest neighbours on point sets with duplicates, a single
  point, K > N; smoothed features finite with norm <= 1, finite gradients.
* clustering (trase.clustering): 1 point, all points equal, zero features, random blobs;
  labels NaN-free, in 0..C-1, contiguous, covering every point; centres unit (or zero).
* scoring (benchmark.scoring): random / empty / full masks under both metric versions;
  per-frame IoU and accuracy in [0, 1] (IoU NaN only for v1 frames where both are empty),
  mIoU / mAcc / pooled IoU in [0, 1], strict-JSON summaries.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from benchmark.scoring import METRICS, binarize, score_frame, score_masks
from trase.clustering import cluster, filter_by_similarity, similarity_to_centre
from trase.smoothing import knn_indices, smooth_features

STATS = {"misc_cases": 0}


@st.composite
def point_sets(draw):
    n = draw(st.integers(1, 80))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    mode = draw(st.sampled_from(["random", "all-equal", "few-distinct", "collinear"]))
    if mode == "all-equal":
        xyz = np.tile(rng.normal(size=3), (n, 1))
    elif mode == "few-distinct":
        xyz = rng.normal(size=(3, 3))[rng.integers(0, 3, n)]
    elif mode == "collinear":
        xyz = np.outer(rng.random(n), [1.0, 2.0, 3.0])
    else:
        xyz = rng.normal(size=(n, 3)) * 10 ** rng.uniform(-6, 3)
    return xyz


@given(xyz=point_sets(), K=st.integers(0, 20), n_keep=st.one_of(st.none(), st.integers(0, 20)),
       zero=st.booleans())
def test_smoothing(xyz, K, n_keep, zero):
    STATS["misc_cases"] += 1
    n = len(xyz)
    idx = knn_indices(xyz, K)
    k = min(K, n)
    assert tuple(idx.shape) == (n, k) and idx.dtype == torch.int64
    if k:
        assert (idx[:, 0] == torch.arange(n)).all(), "each row starts with the point itself"
        assert int(idx.min()) >= 0 and int(idx.max()) < n
        assert all(len(set(r.tolist())) == k for r in idx), "neighbours repeat within a row"
    g = torch.Generator().manual_seed(0)
    f = (torch.zeros(n, 5) if zero else torch.randn(n, 5, generator=g) * 1e3).requires_grad_(True)
    out = smooth_features(f, idx, n_keep=n_keep, generator=g)
    assert out.shape == (n, 5) and torch.isfinite(out).all()
    if k:
        assert float(out.detach().norm(dim=1).max()) <= 1 + 1e-5  # mean of unit (or zero) vectors
    out.sum().backward()
    assert torch.isfinite(f.grad).all()


@st.composite
def feature_sets(draw):
    n = draw(st.integers(1, 400))
    d = draw(st.integers(1, 8))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    mode = draw(st.sampled_from(["blobs", "all-equal", "zeros", "some-zero", "noise", "huge"]))
    if mode == "all-equal":
        f = np.tile(rng.normal(size=d), (n, 1))
    elif mode == "zeros":
        f = np.zeros((n, d))
    elif mode == "blobs":
        c = rng.normal(size=(4, d))
        f = c[rng.integers(0, 4, n)] + 0.01 * rng.normal(size=(n, d))
    else:
        f = rng.normal(size=(n, d)) * (1e6 if mode == "huge" else 1.0)
        if mode == "some-zero":
            f[rng.random(n) < 0.3] = 0.0
    return f.astype(np.float32)


@pytest.mark.parametrize("method,params", [("hdbscan", {}), ("dbscan", {"eps": 0.2}), ("kmeans", {"n_clusters": 5})])
@given(f=feature_sets(), seed=st.integers(0, 10), min_sample=st.sampled_from([0, 20, 500]))
def test_clustering(method, params, f, seed, min_sample):
    STATS["misc_cases"] += 1
    c = cluster(f, method=method, fraction=0.02, seed=seed, min_sample=min_sample, **params)
    n = len(f)
    assert c.labels.shape == (n,) and c.labels.dtype == np.int64
    assert c.labels.min() == 0 and set(np.unique(c.labels)) == set(range(c.n_clusters))
    assert np.isfinite(c.centres).all()
    norms = np.linalg.norm(c.centres, axis=1)
    assert np.all((np.abs(norms - 1) < 1e-4) | (norms < 1e-6))
    if np.unique(f, axis=0).shape[0] == 1:
        assert c.n_clusters == 1
    sim = similarity_to_centre(f, c.labels)
    assert np.isfinite(sim).all() and sim.max() <= 1 + 1e-5 and sim.min() >= -1 - 1e-5
    keep = filter_by_similarity(f, c.labels, 0.9)
    assert keep.shape == (n,) and keep.dtype == bool
    again = cluster(f, method=method, fraction=0.02, seed=seed, min_sample=min_sample, **params)
    assert np.array_equal(c.labels, again.labels), "same seed, same labels"


@st.composite
def mask_pairs(draw):
    h, w = draw(st.integers(1, 20)), draw(st.integers(1, 20))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))

    def one():
        kind = draw(st.sampled_from(["empty", "full", "random", "single"]))
        if kind == "empty":
            return np.zeros((h, w), bool)
        if kind == "full":
            return np.ones((h, w), bool)
        if kind == "single":
            m = np.zeros((h, w), bool)
            m[rng.integers(0, h), rng.integers(0, w)] = True
            return m
        return rng.random((h, w)) < rng.random()

    return one(), one()


@pytest.mark.parametrize("metric", METRICS)
@given(frames=st.lists(mask_pairs(), min_size=1, max_size=6), drop=st.integers(0, 6))
def test_scoring(metric, frames, drop):
    STATS["misc_cases"] += 1
    for p, g in frames:
        fs = score_frame(p, g)
        iou = fs.iou(metric)
        if metric == "v1" and not (p | g).any():
            assert math.isnan(iou)
        else:
            assert 0.0 <= iou <= 1.0
        assert fs.iou(metric) == score_frame(g, p).iou(metric) or math.isnan(iou)  # symmetric
        assert 0.0 <= fs.acc <= 1.0
        assert (fs.iou(metric) == 1.0) == (bool(np.array_equal(p, g)) and p.any())
    names = [f"{i:05d}" for i in range(len(frames))]
    preds = {n: p for n, (p, _) in zip(names, frames)}
    for n in names[drop:drop + 1]:
        preds.pop(n)  # a missing prediction: scored as empty (v1), skipped (official)
    r = score_masks(preds, {n: g for n, (_, g) in zip(names, frames)}, metric)
    for v in (r.miou, r.macc, r.pooled_iou):
        assert math.isnan(v) or 0.0 <= v <= 1.0
    if metric == "official" and r.n_frames:
        assert not math.isnan(r.miou) and not math.isnan(r.pooled_iou)
    d = json.loads(json.dumps(r.to_dict(), allow_nan=False))  # strict JSON: NaN became null
    n_missing = min(1, max(0, len(frames) - drop))
    assert len(d["missing"]) == n_missing
    assert d["metric_version"].startswith(metric + "/")
    assert d["n_frames"] == len(frames) - (n_missing if metric == "official" else 0)


@given(dtype=st.sampled_from([np.uint8, np.uint16, np.int32, np.float32, np.float64, np.bool_]),
       channels=st.sampled_from([0, 1, 3, 4]), seed=st.integers(0, 100))
def test_binarize_any_dtype(dtype, channels, seed):
    STATS["misc_cases"] += 1
    rng = np.random.default_rng(seed)
    shape = (5, 7) if channels == 0 else (5, 7, channels)
    if np.issubdtype(dtype, np.integer):
        a = rng.integers(0, np.iinfo(dtype).max, shape, dtype=dtype)
    elif dtype == np.bool_:
        a = rng.random(shape) < 0.5
    else:
        a = rng.random(shape).astype(dtype)
    b = binarize(a)
    assert b.shape == (5, 7) and b.dtype == np.bool_
