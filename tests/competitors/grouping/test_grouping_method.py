"""gaussian-grouping and sa4d on a tiny scene: two blobs, tracked ids written from the blobs'
rendered labels (1 and 2; 0 where nothing is seen), then learn, group, a click and the oracle."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("trase_bench_grouping")

from trase_bench_grouping.method import NO_TRACK, SA4D, GaussianGrouping, inside_hull
from trase_bench_grouping.settings import GroupingSettings

from benchmark.methods import FittedModel, check_method_class
from benchmark.protocol.prompts import make_benchmark_prompts
from benchmark.scoring import score_masks
from masks.tracked import ids_path, save_ids
from tests.trase.helpers import exact_masks, tiny_scene
from trase.deformation import deformed
from trase.render import rasterize


@dataclasses.dataclass
class _Scene:
    train: list
    test: list
    root: Path = Path("tiny")


def _track_ids(gm, deform, ids, view) -> np.ndarray:
    with torch.no_grad():
        m, q, s = deformed(gm, deform, view.camera.time)
        onehot = torch.nn.functional.one_hot(torch.from_numpy(ids).long(), 2).float()
        out = rasterize(m, q, s, gm.opacities, view.camera, features=onehot)
    lab = np.argmax(out.features.numpy(), axis=2) + 1
    return np.where(out.alpha.numpy() >= 0.5, lab, 0)


@pytest.fixture
def tiny(tmp_path):
    gm, deform, ids, views = tiny_scene()
    masks_dir = tmp_path / "masks"
    for v in views:
        save_ids(ids_path(masks_dir, v.name), _track_ids(gm, deform, ids, v))
    return gm, deform, ids, views, masks_dir


def test_both_are_methods_with_presets():
    for cls in (GaussianGrouping, SA4D):
        assert check_method_class(cls) is None and cls.needs_tracks
    gg = GaussianGrouping().settings("paper", "hypernerf")
    assert (gg.features.dim, gg.features.n_classes, gg.features.lr, gg.features.classifier_lr) == (16, 256, 0.0025, 5e-4)
    assert (gg.features.reg3d_interval, gg.features.reg3d_k, gg.features.reg3d_weight) == (5, 5, 2.0)
    assert gg.features.iterations == 30000 and gg.selection.hull == "union"
    sa = SA4D().settings("paper", "hypernerf")
    assert (sa.features.dim, sa.features.iterations, sa.features.reg3d_interval, sa.selection.hull) == (32, 5000, 1, "filter")
    assert SA4D().settings("paper", "neu3d").features.dim == 16
    assert GaussianGrouping().settings("cpu", "hypernerf").preset == "cpu"
    # SA4D's cpu steps were chosen per kind of rig (docs/notes/competitors.md, "cpu choices")
    assert [SA4D().settings("cpu", d).features.iterations for d in ("hypernerf", "nerfds", "neu3d", "technicolor")] \
        == [500, 500, 1000, 1000]


def _fit(method, tiny, tmp_path, **features):
    gm, deform, _ids, views, masks_dir = tiny
    scene = _Scene(train=views, test=views)
    cfg = method.settings("cpu", "hypernerf")
    cfg.features = dataclasses.replace(cfg.features, **{"iterations": 300, "n_pixels": 0, "reg3d_sample_size": 50,
                                                         "n_classes": 8, **features})
    method.name = method.name or type(method).__name__
    fitted = method.fit(scene, gm, deform, masks_dir, cfg, tmp_path / "fit", progress=False)
    return scene, fitted


@pytest.mark.parametrize("cls", [GaussianGrouping, SA4D])
def test_fit_click_and_oracle_on_two_blobs(cls, tiny, tmp_path):
    gm, deform, ids, views, _ = tiny
    method = cls()
    scene, fitted = _fit(method, tiny, tmp_path, **({"field_width": 32} if cls is SA4D else {}))
    assert fitted.features.shape[0] == len(ids)
    # each blob's gaussians take their track's class (1 and 2)
    assert np.mean(fitted.labels[ids == 0] == 1) > 0.9 and np.mean(fitted.labels[ids == 1] == 2) > 0.9
    gts = [exact_masks(gm, deform, ids, v).masks[0] for v in views]
    prompts = make_benchmark_prompts(views, gts)
    preds = method.segment(fitted, scene, prompts)
    names = [str(i) for i in range(len(views))]
    assert fitted.stats["click_clusters"][0] in (1, 2)
    assert score_masks(dict(zip(names, preds)), dict(zip(names, gts))).miou > 0.8
    opreds, classes = method.segment_oracle(fitted, scene, gts)
    assert len(opreds) == len(views) and classes == fitted.stats["selected_clusters"]
    fitted.save(tmp_path / "out")  # the benchmark reloads it: the weights travel in fitted.json
    back = FittedModel.load(tmp_path / "out", gm, deform, method.settings_class())
    assert method.click_clusters(back, scene, prompts) == fitted.stats["click_clusters"]


def test_the_oracle_takes_no_class_a_click_cannot_choose(tiny, tmp_path):
    # a click on class 0 ("no track") selects nothing, so the oracle, a bound on what clicks can
    # select, never takes it, even where its gaussians lie inside the ground truth
    gm, deform, ids, views, _ = tiny
    method = GaussianGrouping()
    scene, fitted = _fit(method, tiny, tmp_path, iterations=20)
    gts = [exact_masks(gm, deform, ids, v).masks[0] for v in views]  # blob 0's masks
    _, classes = method.segment_oracle(fitted, scene, gts)
    assert classes and NO_TRACK not in classes
    fitted.labels = np.where(ids == 0, NO_TRACK, fitted.labels)  # blob 0's gaussians read as "no track"
    _, classes = method.segment_oracle(fitted, scene, gts)
    assert classes == []


def test_a_click_on_nothing_chooses_nothing(tiny, tmp_path):
    from trase.prompts import Click

    method = GaussianGrouping()
    scene, fitted = _fit(method, tiny, tmp_path, iterations=20)
    prompts = make_benchmark_prompts(scene.test, [exact_masks(*tiny[:3], v).masks[0] for v in scene.test])
    far = dataclasses.replace(prompts, clicks=[Click(0.5, 0.5, view=scene.test[0].name)])
    assert method.click_clusters(fitted, scene, far) == [-1]
    assert not any(m.any() for m in method.segment(fitted, scene, far))


def test_track_ids_beyond_the_classes_widen_the_classifier(tiny, tmp_path):
    # the tiny scene's tracks number ids 0..2: with n_classes=2 the classifier has 3 outputs,
    # recorded, and a reloaded model is built with them
    gm, deform, _ids, _views, _ = tiny
    method = GaussianGrouping()
    _scene, fitted = _fit(method, tiny, tmp_path, n_classes=2, iterations=1)
    assert fitted.stats["n_classes"] == 3
    assert method.probabilities_at(fitted, 0.5).shape == (gm.num_gaussians, 3)
    fitted.save(tmp_path / "out")
    back = FittedModel.load(tmp_path / "out", gm, deform, method.settings_class())
    assert method.probabilities_at(back, 0.5).shape == (gm.num_gaussians, 3)


def test_negative_track_ids_are_one_line_errors(tiny):
    from trase_bench_grouping.train import IdentityTrainingError, train_identity

    gm, deform, _ids, views, _ = tiny
    cfg = dataclasses.replace(GaussianGrouping().settings("cpu", "hypernerf").features, iterations=1)
    with pytest.raises(IdentityTrainingError, match="negative track id -1"):
        train_identity(gm, deform, views, lambda v: -np.ones((v.camera.height, v.camera.width), int), cfg)


def test_no_ids_files_is_a_one_line_error(tmp_path):
    from benchmark.methods import MethodError

    gm, deform, _ids, views = tiny_scene()
    method = GaussianGrouping()
    method.name = "gaussian-grouping"
    with pytest.raises(MethodError, match="tracked ids"):
        method.learn(_Scene(views, views), gm, deform, tmp_path, method.settings("cpu", "hypernerf"), tmp_path / "w",
                     progress=False)


def test_hull_union_fills_and_filter_drops_outliers():
    rng = np.random.default_rng(0)
    cube = rng.uniform(-1, 1, size=(200, 3))
    far = np.array([[10.0, 10.0, 10.0]])
    pts = np.concatenate([cube, far, [[0.0, 0.0, 0.0]]])
    chosen = np.zeros(len(pts), bool)
    chosen[:150] = True
    chosen[200] = True  # an outlier the IQR rule drops
    inside = inside_hull(pts, chosen, 1.0)
    assert inside[201] and not inside[200]  # the centre is inside, the outlier is not


def test_hull_by_facet_planes_matches_the_delaunay_reference():
    """The plane test against the public code's Delaunay.find_simplex: the same points inside,
    the chosen (hull) points among them; a flat or too small choice has no inside."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(1)
    for shape in ("ball", "slab", "elongated"):
        pts = rng.normal(size=(3000, 3)) * {"ball": [1, 1, 1], "slab": [3, 3, 0.05], "elongated": [10, 0.5, 0.5]}[shape]
        chosen = np.linalg.norm(pts / pts.std(axis=0), axis=1) < 1.0  # a blob in the middle
        inside = inside_hull(pts, chosen, 1e9)  # no outliers dropped: the hull of every chosen point
        reference = Delaunay(pts[chosen]).find_simplex(pts) >= 0
        assert inside[chosen].all()
        assert (inside == reference).mean() > 0.999, shape  # at most points on a facet differ
    flat = np.c_[rng.normal(size=(50, 2)), np.zeros(50)]
    assert not inside_hull(flat, np.ones(50, bool), 1.0).any()
    assert not inside_hull(pts, np.arange(len(pts)) < 4, 1.0).any()


def _logits(*rows) -> torch.Tensor:
    """[K, 8] logits of a click window whose pixels prefer classes in the order given."""
    out = torch.zeros(len(rows), 8)
    for i, order in enumerate(rows):
        for rank, k in enumerate(order):
            out[i, k] = 10.0 - rank
    return out


def test_vote_among_the_allowed_classes():
    from trase_bench_grouping.method import vote

    window = _logits([3, 5, 2], [3, 5, 2], [5, 3, 2])
    assert vote(window) == 3 and vote(window, exclude={3}) == 5 and vote(window, exclude=set(range(8)) - {2}) == 2
    assert vote(None) == -1 and vote(window, exclude=set(range(8))) == -1
    assert vote(_logits([NO_TRACK, 4])) == -1 and vote(_logits([NO_TRACK, 4]), exclude={NO_TRACK}) == 4


@pytest.mark.parametrize("votes,expected", [("ruled-out", ([5], [3, 3, 5])), ("any", ([3], [3, 4, 3]))])
def test_a_negative_click_removes_a_selected_class(monkeypatch, votes, expected):
    """A click that reads class 3 (the wall) selects it; a negative click on a pixel that class 3
    lights from behind the ball (class 4 in front) removes 3 under "ruled-out", and the next
    positive click at the first pixel takes the next class there (5). Under "any" the negative
    click reads 4, which was not selected: nothing changes and 3 stays."""
    from trase.prompts import Click

    clicks = [Click(1.0, 1.0), Click(2.0, 2.0, positive=False), Click(1.0, 1.0)]
    windows = [_logits([3, 5]), _logits([4, 3]), _logits([3, 5])]
    method = GaussianGrouping()
    monkeypatch.setattr(method, "click_logits", lambda fitted, scene, prompts: iter(windows))
    config = GroupingSettings()
    config.selection.click_votes = votes
    fitted = FittedModel(np.zeros((1, 1)), np.zeros(1, np.int64), np.ones(1, bool), {}, {}, config)
    prompts = dataclasses.make_dataclass("P", [("clicks", list)])(clicks)
    assert method.click_selection(fitted, None, prompts) == expected
