import numpy as np
import pytest
from mask_testutils import blob_maskset

from masks import MaskError, MaskSet
from masks.sampling import grid_shape, mask_centroids, sample_masks, sample_pixels


def test_random_rule_probability_and_determinism():
    ms = blob_maskset(n=40)
    counts = [len(sample_masks(ms, "random", 10, np.random.default_rng(s))) for s in range(400)]
    assert abs(np.mean(counts) - 10) < 0.5
    a = sample_masks(ms, "random", 10, np.random.default_rng(7))
    b = sample_masks(ms, "random", 10, np.random.default_rng(7))
    assert np.array_equal(a, b)
    assert np.array_equal(sample_masks(ms, "random", 40, np.random.default_rng(0)), np.arange(40))
    assert np.array_equal(sample_masks(ms, "random", 99, np.random.default_rng(0)), np.arange(40))
    assert len(sample_masks(ms, "random", 0, np.random.default_rng(0))) == 0


def test_area_and_score_rules():
    ms = blob_maskset(n=12)
    idx = sample_masks(ms, "area", 4, np.random.default_rng(0))
    assert len(idx) == 4 and ms.area[idx].min() >= np.sort(ms.area)[-4]
    idx = sample_masks(ms, "score", 3, np.random.default_rng(0))
    assert set(idx) == set(np.argsort(-ms.score)[:3])
    assert len(sample_masks(ms, "area", 100, np.random.default_rng(0))) == 12
    with pytest.raises(MaskError):
        sample_masks(blob_maskset(score=False), "score", 3, np.random.default_rng(0))
    with pytest.raises(MaskError):
        sample_masks(ms, "nope", 3, np.random.default_rng(0))


def test_area_ties_are_randomised():
    m = np.zeros((6, 4, 4), bool)
    for i in range(6):
        m[i, i % 4, :] = True  # all area 4
    ms = MaskSet.from_masks(m)
    picks = {tuple(sample_masks(ms, "area", 2, np.random.default_rng(s))) for s in range(30)}
    assert len(picks) > 1


def test_grid_shape_and_rule():
    assert grid_shape(50, 120, 160) == (5, 10)
    assert grid_shape(50, 160, 120) == (10, 5)
    assert grid_shape(4, 100, 100) == (2, 2)
    h, w = 40, 40
    m = np.zeros((5, h, w), bool)
    m[0, :20, :20] = True  # cell (0,0), area 400
    m[1, 2:8, 2:8] = True  # cell (0,0), area 36 -> loses to 0
    m[2, 25:30, 25:30] = True  # cell (1,1)
    m[3, 20:40, 22:40] = True  # centroid (31, 30) -> cell (1,1), larger than 2
    m[4, 0:10, 30:40] = True  # cell (0,1)
    ms = MaskSet.from_masks(m)
    assert np.allclose(mask_centroids(m)[0], [10, 10])
    assert list(sample_masks(ms, "grid", 4, np.random.default_rng(0))) == [0, 3, 4]
    big = blob_maskset(n=200, h=60, w=80)
    idx = sample_masks(big, "grid", 50, np.random.default_rng(0))
    assert 0 < len(idx) <= 50 and len(set(idx)) == len(idx)


def test_sample_pixels():
    valid = np.zeros((50, 60), bool)
    valid[:, :30] = True
    idx = sample_pixels(valid, 600, np.random.default_rng(0))
    assert valid.reshape(-1)[idx].all()
    sizes = [len(sample_pixels(np.ones((50, 60), bool), 600, np.random.default_rng(s))) for s in range(50)]
    assert abs(np.mean(sizes) - 600) < 15
    assert np.array_equal(idx, sample_pixels(valid, 600, np.random.default_rng(0)))
