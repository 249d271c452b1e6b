"""Pure pieces of the perf suites: statistics, exponent fits, Pareto front, neighbour-set
agreement, cluster centres and assignment. Fast and deterministic."""

import numpy as np
import pytest

from benchmark.perf import common
from benchmark.perf.cluster import centres_of, make_features, sample_then_assign
from benchmark.perf.knn import (
    agreement,
    exact_knn,
    knn_ckdtree_all_cores,
    knn_sklearn,
    knn_trase,
    make_points,
)
from benchmark.perf.pareto import figure, pareto_front, settings_grid
from benchmark.perf.pipeline import fit_exponents, stage_table


def test_stats_median_and_spread():
    s = common.stats([3.0, 1.0, 2.0, 10.0])
    assert s["median"] == 2.5 and s["spread"] == 9.0 and s["all"] == [3.0, 1.0, 2.0, 10.0]
    assert common.fmt(s) == "2.500s (+-4.500)"
    assert common.ratio({"median": 4.0}, {"median": 2.0}) == 2.0


def test_time_repeats_counts_calls_and_stops_at_budget():
    calls = []
    t, out = common.time_repeats(lambda: calls.append(1) or len(calls), repeats=3, warmup=2)
    assert len(calls) == 5 and out == 5 and len(t["all"]) == 3
    calls.clear()
    t, _ = common.time_repeats(lambda: calls.append(1), repeats=50, budget_s=0.0)
    assert len(calls) == 1 and len(t["all"]) == 1  # at least one call, then the budget stops it


def test_table_aligns_columns():
    text = common.table([["a", "1"], ["bbb", "22"]], ["name", "n"])
    lines = text.splitlines()
    assert len(lines) == 4 and len({len(line) for line in lines}) == 1


def test_fit_exponents_recovers_known_powers():
    rng = np.random.default_rng(0)
    pts = []
    for _ in range(12):
        px, g = float(rng.uniform(1e4, 1e6)), float(rng.uniform(1e3, 1e5))
        pts.append({"pixels": px, "gaussians": g, "seconds": 3e-7 * px**1.5 * g**0.5})
    f = fit_exponents(pts)
    assert f["joint"]["pixels_exponent"] == pytest.approx(1.5, abs=1e-6)
    assert f["joint"]["gaussians_exponent"] == pytest.approx(0.5, abs=1e-6)
    # one driver only: exact when the other is constant
    pts = [{"pixels": p, "gaussians": 10.0, "seconds": 2.0 * p**2} for p in (10.0, 100.0, 1000.0)]
    f = fit_exponents(pts)
    assert f["pixels_exponent"] == pytest.approx(2.0) and f["gaussians_exponent"] is None and f["joint"] is None


def test_fit_exponents_degenerate_inputs():
    assert fit_exponents([])["pixels_exponent"] is None
    one = fit_exponents([{"pixels": 10.0, "gaussians": 5.0, "seconds": 1.0}])
    assert one["n_points"] == 1 and one["pixels_exponent"] is None and one["joint"] is None
    zero = fit_exponents([{"pixels": 10.0, "gaussians": 5.0, "seconds": 0.0}] * 3)  # log(0) left out
    assert zero["n_points"] == 0
    # drivers that grow together: no joint split, said so
    tied = [{"pixels": p, "gaussians": 2 * p * (1 + 1e-3 * k), "seconds": p} for k, p in enumerate((10.0, 100.0, 1e3))]
    f = fit_exponents(tied)
    assert f["joint"] is None and "collinear" in f["joint_skipped"] and f["pixels_exponent"] == pytest.approx(1.0, abs=1e-2)


def test_stage_table_flattens_fit_timings():
    rec = {"stages": {"masks": {"seconds": 1.0, "peak_rss_mb": 10.0, "skipped": False},
                      "fit": {"seconds": 5.0, "peak_rss_mb": 20.0, "info": {"timings": {
                          "features_train": 4.0, "clustering": 0.5, "n_usable_views": 3}}}}}
    rec["stages"]["evaluate"] = {"seconds": 2.0, "peak_rss_mb": 20.0,
                                 "info": {"timings": {"features_train": 4.0, "render": 1.5}}}
    t = stage_table(rec)
    # evaluate's copy of fit's features_train is listed once
    assert set(t) == {"masks", "fit", "evaluate", "fit.features_train", "fit.clustering", "evaluate.render"}
    assert t["fit.features_train"]["seconds"] == 4.0 and t["masks"]["peak_rss_mb"] == 10.0


def test_pareto_front_and_grid():
    pts = [(1.0, 0.5), (2.0, 0.7), (3.0, 0.6), (1.5, 0.5), (4.0, 0.9), (2.0, 0.7)]
    # (3, .6) is beaten by (2, .7); (1.5, .5) by (1, .5); the two equal (2, .7) do not dominate each other
    assert pareto_front(pts) == [0, 1, 5, 4]
    g = settings_grid({"a": 1, "b": 2}, {"a": [1, 3], "b": [5]})
    assert g == [{"a": 1, "b": 2}, {"a": 3, "b": 2}, {"a": 1, "b": 5}]


def test_pareto_figure_keeps_a_long_title_and_plain_seconds_inside_the_figure():
    import matplotlib.pyplot as plt

    runs = [{"label": "full", "seconds": 352.0, "miou": 0.952}, {"label": "static", "seconds": 322.0, "miou": 0.949},
            {"label": "converged", "seconds": 281.0, "miou": 0.946}]
    title = ("skips on dnerf/mutant (as published): foreground IoU (one click, held-out views) against "
             "geometry + features time")
    fig = figure(runs, [2, 1, 0], title, "geometry + features time (s)", "foreground IoU")
    try:
        fig.canvas.draw()
        ax = fig.axes[0]
        box, frame = ax.title.get_window_extent(), fig.bbox
        assert box.x0 >= frame.x0 and box.x1 <= frame.x1  # wrapped, not cut at the figure's edge
        labels = [t.get_text() for t in ax.get_xticklabels(minor=True) + ax.get_xticklabels() if t.get_text()]
        assert labels and all("times" not in x and "^" not in x for x in labels)  # 300, not 3x10^2
    finally:
        plt.close(fig)


def test_knn_alternatives_agree_with_brute_force():
    pts = make_points(3000, seed=1)
    rows = np.arange(0, 3000, 37)
    ids, d2 = exact_knn(pts, rows)
    for fn in (knn_trase, knn_ckdtree_all_cores, knn_sklearn):
        a = agreement(pts, fn(pts), rows, ids, d2)
        assert a["equal_up_to_ties"] == 1.0 and a["self_included"] == 1.0


def test_knn_agreement_detects_wrong_neighbours():
    pts = make_points(2000, seed=2)
    rows = np.arange(0, 2000, 50)
    ids, d2 = exact_knn(pts, rows)
    wrong = knn_ckdtree_all_cores(pts)
    wrong[rows, -1] = (wrong[rows, -1] + 997) % 2000  # replace the farthest neighbour
    a = agreement(pts, wrong, rows, ids, d2)
    assert a["equal_sets"] < 0.1 and a["equal_up_to_ties"] < 0.1


def test_cluster_centres_match_trase_clustering():
    from trase import clustering

    x, known = make_features(3000, seed=3)
    values, ref = clustering._centres(x, known)
    got = centres_of(x, known)
    np.testing.assert_allclose(got, ref, atol=1e-5)
    assert got.shape == (len(values), 32)


def test_sample_then_assign_with_known_labeller_recovers_clusters():
    from sklearn.metrics import adjusted_rand_score

    x, known = make_features(4000, seed=4)
    truth = {tuple(np.round(r, 6)): k for r, k in zip(x, known)}
    labels = sample_then_assign(x, 2000, lambda s: np.array([truth[tuple(np.round(r, 6))] for r in s]))
    keep = known >= 0
    assert labels.min() == 0 and labels.max() == len(np.unique(labels)) - 1
    assert adjusted_rand_score(known[keep], labels[keep]) > 0.95


def test_make_features_known_structure():
    x, known = make_features(5000, seed=0)
    assert x.shape == (5000, 32) and x.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1.0, atol=1e-5)
    assert 0.005 < np.mean(known == -1) < 0.04 and len(np.unique(known[known >= 0])) >= 40
