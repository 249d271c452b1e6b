import math

import numpy as np
import pytest

from trase.feature_stats import feature_space_stats


def test_hand_computed():
    f = np.array([[1, 0], [2, 0], [0, 3], [0, 1]], float)
    s = feature_space_stats(f, [0, 0, 1, 1])
    assert s.intra == pytest.approx(0.0, abs=1e-6)
    assert s.inter == pytest.approx(math.sqrt(2), abs=1e-6)
    assert s.n_clusters == 2


def test_spread_cluster_has_positive_intra():
    f = np.array([[1, 0], [0, 1]], float)
    s = feature_space_stats(f, [0, 0])
    # centre (1,1)/sqrt2; distance of each unit vector = sqrt(2 - sqrt2)
    assert s.intra == pytest.approx(math.sqrt(2 - math.sqrt(2)), abs=1e-6)
    assert math.isnan(s.inter) and s.to_dict()["inter"] is None


def test_zero_and_empty():
    s = feature_space_stats(np.zeros((3, 4)), [0, 1, 1])
    assert np.isfinite(s.intra) and np.isfinite(s.inter)
    assert feature_space_stats(np.zeros((0, 4)), []).n_gaussians == 0
