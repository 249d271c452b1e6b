import numpy as np
import pytest
import torch

import baselines  # noqa: F401  (registers the baseline objectives with trase.objectives)
from tests.trase.helpers import exact_masks, tiny_scene
from trase.clustering import cluster
from trase.features import FeatureConfig, FeatureTrainingError, build_sample, train_features


def _train(tmp_path, iterations=120, **kw):
    gm, deform, ids, views = tiny_scene()
    masks = {v.name: exact_masks(gm, deform, ids, v) for v in views}
    cfg = FeatureConfig(dim=8, iterations=iterations, n_pixels=300, n_masks=3, knn=4, knn_keep=2, lr=0.02, **kw)
    res = train_features(gm, deform, views, lambda v: masks[v.name], cfg, cache_dir=tmp_path, progress=False)
    return res, ids


def test_features_separate_objects(tmp_path):
    res, ids = _train(tmp_path)
    f = torch.nn.functional.normalize(res.features, dim=1)
    a, b = f[ids == 0], f[ids == 1]
    assert (a @ b.T).mean() < 0.3 < (a @ a.T).mean()
    c = cluster(res.features.numpy(), method="kmeans", n_clusters=2)
    agree = (c.labels == ids).mean()
    assert max(agree, 1 - agree) > 0.95
    assert res.timings["per_step"] > 0 and res.path_stats["bytes_per_view_max"] > 0
    assert np.isfinite(res.features.numpy()).all()


def test_deterministic_and_fastpath_matches_rasterizer(tmp_path):
    r1, _ = _train(tmp_path / "a", iterations=30, fastpath=True)
    r2, _ = _train(tmp_path / "b", iterations=30, fastpath=True)
    assert torch.equal(r1.features, r2.features)
    assert r1.path_stats["path"] == "fastpath"
    r3, _ = _train(tmp_path / "c", iterations=30, fastpath=False, render_backend="numba")
    assert (r1.history[0]["loss"] - r3.history[0]["loss"]) < 1e-5
    assert (r1.features - r3.features).abs().max() < 1e-2


def test_auto_fastpath_only_when_views_are_drawn_often(tmp_path):
    from trase.features import FASTPATH_MIN_USES, FeatureTrainingError, use_fastpath

    assert use_fastpath("auto", FASTPATH_MIN_USES * 50, 50)
    assert not use_fastpath("auto", 1000, 450)  # 450 views: each drawn ~2 times
    assert use_fastpath(True, 1, 5000) and not use_fastpath(False, 10**6, 1)
    try:
        use_fastpath("sometimes", 10, 1)
    except FeatureTrainingError as exc:
        assert "sometimes" in str(exc)
    else:
        raise AssertionError("a bad fastpath setting must be an error")
    # the tiny scene has 4 views: 10 steps draw each ~2.5 times -> rasterizer; 20 -> fast path
    few, _ = _train(tmp_path / "few", iterations=10)
    many, _ = _train(tmp_path / "many", iterations=4 * FASTPATH_MIN_USES)
    assert few.path_stats["path"] == "rasterizer" and many.path_stats["path"] == "fastpath"


def test_degenerate_views_and_single_gaussian(tmp_path):
    from masks.maskset import MaskSet

    gm, deform, _, views = tiny_scene(n_per=1)
    empty = MaskSet.empty(views[0].camera.height, views[0].camera.width)
    cfg = FeatureConfig(dim=4, iterations=5, n_pixels=50, knn=16)
    res = train_features(gm, deform, views, lambda v: empty, cfg, progress=False)  # no masks at all
    assert res.features.shape == (2, 4) and torch.isfinite(res.features).all()
    full = MaskSet.from_masks(np.ones((1, views[0].camera.height, views[0].camera.width), bool))
    res = train_features(gm, deform, views, lambda v: full, cfg, progress=False)  # one mask covers all
    assert torch.isfinite(res.features).all() and len(res.history) > 0


def test_build_sample_membership():
    from masks.maskset import MaskSet

    m = np.zeros((2, 4, 5), bool)
    m[0, :2] = True
    m[1, :, :2] = True
    ms = MaskSet.from_masks(m)
    s = build_sample(ms, "area", 2, 1e9, np.random.default_rng(0))
    pix = s.pixels.numpy()
    assert (ms.covered.reshape(-1)[pix]).all()
    assert np.array_equal(s.membership.numpy(), m.reshape(2, -1)[:, pix].T)
    np.testing.assert_allclose(s.pixel_mean_area.numpy(), ms.pixel_mean_area.reshape(-1)[pix])


def test_smoothed_features_are_normalised_again_before_rendering():
    # public trainer: render(..., norm_gaussian_features=True) after the neighbour mean
    from trase.features import render_ready
    from trase.smoothing import knn_indices

    gen = torch.Generator().manual_seed(0)
    feats = torch.randn(40, 8, generator=gen)
    knn = knn_indices(torch.randn(40, 3, generator=gen), 6)
    on = render_ready(feats, knn, FeatureConfig(knn=6, knn_keep=3), torch.Generator().manual_seed(1))
    off = render_ready(feats, knn, FeatureConfig(knn=6, knn_keep=3, renormalize=False),
                       torch.Generator().manual_seed(1))
    assert torch.allclose(on.norm(dim=1), torch.ones(40), atol=1e-6)
    assert (off.norm(dim=1) < 0.999).any()  # a mean of unit vectors is shorter
    assert torch.allclose(on, torch.nn.functional.normalize(off, dim=1), atol=1e-6)


class _Recorder(torch.nn.Module):
    """An objective that keeps what the trainer hands it (uses the norm regulariser)."""

    uses_norm_regulariser = True

    def __init__(self):
        super().__init__()
        self.seen = []

    def forward(self, features, sample):
        self.seen.append((features.detach().clone(), sample))
        return (features ** 2).sum() * 0.0, {}

    def gaussian_loss(self, features, xyz, rng=None):
        return None


def test_norm_regulariser_sees_the_whole_view_unless_told_sampled(tmp_path, monkeypatch):
    import trase.features as tf

    gm, deform, ids, views = tiny_scene()
    masks = {v.name: exact_masks(gm, deform, ids, v) for v in views}
    for rule in ("image", "sampled"):
        rec = _Recorder()
        monkeypatch.setattr(tf, "get_objective", lambda name, rec=rec, **kw: rec)
        cfg = FeatureConfig(dim=4, iterations=6, n_pixels=100, n_masks=3, knn=4, knn_keep=2,
                            norm_reg_pixels=rule, fastpath=True)
        train_features(gm, deform, views, lambda v: masks[v.name], cfg, cache_dir=tmp_path / rule, progress=False)
        for rendered, sample in rec.seen:
            if rule == "sampled":
                assert sample.image_features is None
                continue
            H, W = views[sample.view].camera.height, views[sample.view].camera.width
            assert sample.image_features.shape == (H * W, 4)
            assert torch.allclose(sample.image_features[sample.pixels], rendered)
            outside = ~masks[views[sample.view].name].covered.reshape(-1)
            assert outside.any()  # the view has pixels in no mask, and they are rendered too
    try:
        train_features(gm, deform, views, lambda v: masks[v.name],
                       FeatureConfig(dim=4, iterations=2, norm_reg_pixels="some"), progress=False)
    except tf.FeatureTrainingError as exc:
        assert "norm_reg_pixels" in str(exc)
    else:
        raise AssertionError("an unknown norm_reg_pixels must be an error")


def test_norm_regulariser_averages_over_the_image_features_when_given():
    from trase.objectives import PixelSample, get_objective

    sample = PixelSample(pixels=torch.arange(4), membership=torch.tensor([[1], [1], [0], [0]], dtype=torch.bool),
                         mask_area=torch.tensor([2.0]), pixel_mean_area=torch.tensor([2.0, 2.0, 0.0, 0.0]))
    feats = torch.ones(4, 2) / 2 ** 0.5  # unit norm at the sampled pixels
    for name in ("trase", "trase-hard", "trase-all"):
        _, stats = get_objective(name)(feats, sample)
        assert stats["reg"] < 1e-9
        sample.image_features = torch.cat([feats, torch.zeros(4, 2)])  # half the view renders nothing
        _, stats = get_objective(name)(feats, sample)
        assert abs(stats["reg"] - 0.25) < 1e-6  # (1 - 0.5)^2
        sample.image_features = None


@pytest.mark.parametrize("stopping", [{}, {"stop_interval": 10, "stop_patience": 2, "stop_min_delta": 0.0,
                                          "stop_holdout_every": 2}])
def test_a_killed_training_resumes_from_its_checkpoint_bit_for_bit(tmp_path, monkeypatch, stopping):
    import trase.features as tf

    gm, deform, ids, views = tiny_scene()
    masks = {v.name: exact_masks(gm, deform, ids, v) for v in views}
    cfg = FeatureConfig(dim=8, iterations=40, n_pixels=300, n_masks=3, knn=4, knn_keep=2, lr=0.02, fastpath=True,
                        **stopping)
    train = lambda d, **kw: train_features(gm, deform, views, lambda v: masks[v.name], cfg, cache_dir=d,
                                           progress=False, **kw)
    whole = train(tmp_path / "whole")
    ckpt = tmp_path / "cut" / "features_checkpoint.pt"
    draw = tf._FeatureStep.draw
    calls = {"n": 0}

    def killed_at_step_25(self):
        calls["n"] += 1
        if calls["n"] > 25:
            raise KeyboardInterrupt  # the job is killed mid-stage
        return draw(self)

    monkeypatch.setattr(tf._FeatureStep, "draw", killed_at_step_25)
    with pytest.raises(KeyboardInterrupt):
        train(tmp_path / "cut", checkpoint=ckpt, checkpoint_every_s=0.0)  # saved after every step
    assert torch.load(ckpt, weights_only=False)["step"] == 25
    monkeypatch.setattr(tf._FeatureStep, "draw", draw)
    resumed = train(tmp_path / "cut", checkpoint=ckpt, checkpoint_every_s=0.0)
    assert resumed.timings["resumed_from_step"] == 25 and whole.timings["resumed_from_step"] == 0
    assert torch.equal(resumed.features, whole.features) and torch.equal(resumed.raw_features, whole.raw_features)
    assert [h["loss"] for h in resumed.history] == [h["loss"] for h in whole.history]
    assert resumed.stopping == whole.stopping  # the checks before the kill came back with the checkpoint
    if stopping:  # checks every 10 steps up to where it stopped (or the cap)
        assert [c[0] for c in whole.stopping["checks"]][:2] == [10, 20] and len(whole.stopping["held_out"]) == 2
    assert not ckpt.exists()  # removed once the training ended
    # a checkpoint of other features (another width) is not resumed from
    other = tmp_path / "other.pt"
    torch.save({"features": torch.zeros(3, 2)}, other)
    assert train(tmp_path / "o", checkpoint=other).timings["resumed_from_step"] == 0


def test_the_stage_stops_when_the_held_out_loss_stops_falling(tmp_path):
    # a fall of 100 times the first loss never comes: the first check (10) sets the baseline, the next stops
    res, _ = _train(tmp_path, iterations=60, stop_interval=10, stop_patience=1, stop_min_delta=100.0,
                    stop_holdout_every=2)
    st = res.stopping
    assert st["stopped_at"] == 20 and st["cap"] == 60 and [c[0] for c in st["checks"]] == [10, 20]
    assert len(st["held_out"]) == 2 and res.timings["n_usable_views"] == 2  # 2 of the 4 views held out
    assert res.history[-1]["step"] == 19 and np.isfinite(st["best"])
    # the same settings without stopping train on every view for the whole schedule
    full, _ = _train(tmp_path / "full", iterations=60)
    assert full.stopping is None and full.timings["n_usable_views"] == 4 and full.history[-1]["step"] == 59


def test_too_few_views_to_hold_out_train_the_whole_schedule_and_say_so(tmp_path):
    res, _ = _train(tmp_path, iterations=30, stop_interval=10, stop_patience=1, stop_min_delta=1.0,
                    stop_holdout_every=10)
    assert res.stopping["stopped_at"] is None and "none held out" in res.stopping["why"]
    assert res.history[-1]["step"] == 29


def test_no_view_is_held_out_where_no_stop_could_come_before_the_end(tmp_path):
    # checks at 10 and 20 of 20 steps: the earliest stop (patience 2) would be at 30
    res, _ = _train(tmp_path, iterations=20, stop_interval=10, stop_holdout_every=2)
    assert res.timings["n_usable_views"] == 4 and res.stopping["held_out"] == []
    assert "no stop possible before the schedule's end" in res.stopping["why"]


def test_bad_stopping_settings_are_refused_before_any_work(tmp_path):
    with pytest.raises(FeatureTrainingError, match="stop_holdout_every must be >= 2"):
        _train(tmp_path, iterations=20, stop_interval=10, stop_holdout_every=1)
    with pytest.raises(FeatureTrainingError, match="patience >= 1"):
        _train(tmp_path, iterations=20, stop_interval=10, stop_patience=0)
