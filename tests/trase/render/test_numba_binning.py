"""Tile binning pieces of the numba backend: the radix argsort against numpy's stable sort,
and binning invariants (depth order per tile, entry maps) on edge cases."""

from __future__ import annotations

import numpy as np
import pytest

from trase.render.numba_kernels import bin_gaussians, stable_argsort


@pytest.mark.parametrize(
    "keys",
    [
        np.random.default_rng(0).standard_normal(3000),
        np.random.default_rng(1).random(3000).astype(np.float32).astype(np.float64) + 2.0,  # float32 depths
        np.round(np.random.default_rng(2).standard_normal(2000), 1),  # many ties, -0.0 and +0.0
        np.array([0.0, -0.0, 1.0, -1.0, np.inf, -np.inf, 3.0, 3.0, np.nan, 5e-324, -5e-324, 0.0]),
        np.full(50, 7.0),
        np.array([]),
    ],
)
def test_stable_argsort_matches_numpy(keys):
    assert np.array_equal(stable_argsort(keys), np.argsort(keys, kind="stable"))


def test_binning_all_in_one_tile_and_empty_rects():
    n = 200
    rng = np.random.default_rng(3)
    rects = np.zeros((n, 4), np.int64)
    rects[:, 1] = 1  # every gaussian in tile (0, 0) of a 3 x 2 grid
    rects[:, 3] = 1
    rects[::7] = 0  # some culled (empty rect)
    depths = np.round(rng.random(n), 2)  # ties
    tile_off, entries, g_ptr, g_pos = bin_gaussians(rects, depths, 3, 2)
    kept = np.flatnonzero(rects[:, 1] > 0)
    assert tile_off.tolist() == [0, len(kept)] + [len(kept)] * 5  # the other tiles are empty
    assert np.array_equal(entries, kept[np.argsort(depths[kept], kind="stable")])
    for g in range(n):  # g_pos lists each gaussian's entries
        assert all(entries[g_pos[j]] == g for j in range(g_ptr[g], g_ptr[g + 1]))
    assert g_ptr[-1] == len(entries)
