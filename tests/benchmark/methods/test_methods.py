import dataclasses
from pathlib import Path

import numpy as np
import pytest

import masks as masklib
from benchmark.methods import FittedModel, MethodError, get_method
from benchmark.methods.trase_method import TraseMethod
from benchmark.methods.trase_presets import TraseSettings
from benchmark.protocol.prompts import make_benchmark_prompts
from benchmark.scoring import score_masks
from tests.trase.helpers import exact_masks, tiny_scene


def _small_config(method):
    cfg = method.settings("cpu", "hypernerf")
    cfg.features.n_pixels, cfg.features.n_masks = 300, 3.0
    cfg.filter_threshold = 0.5
    return cfg


@dataclasses.dataclass
class _Scene:
    train: list
    test: list
    root: Path = Path("tiny")


def test_registry():
    m = get_method("trase")
    assert isinstance(m, TraseMethod) and m.name == "trase" and m.objective == "trase"
    assert get_method("trase", objective="trase-hard").objective == "trase-hard"
    with pytest.raises(MethodError, match="unknown method 'nope'"):
        get_method("nope")


def test_fit_segment_end_to_end(tmp_path):
    gm, deform, ids, views = tiny_scene()
    masks_dir = tmp_path / "masks"
    for v in views:
        masklib.save(masklib.mask_path(masks_dir, v.name), exact_masks(gm, deform, ids, v))
    scene = _Scene(train=views, test=views)
    method = get_method("trase")
    cfg = _small_config(method)
    cfg.features = dataclasses.replace(cfg.features, iterations=120, dim=8, knn=4, knn_keep=2, lr=0.02)
    cfg.clustering = dataclasses.replace(cfg.clustering, method="kmeans", params={"n_clusters": 2})
    fitted = method.fit(scene, gm, deform, masks_dir, cfg, tmp_path / "fit", progress=False)
    assert fitted.labels.shape == (len(ids),) and fitted.stats["n_clusters"] == 2
    gts = [exact_masks(gm, deform, ids, v).masks[0] for v in views]  # object 0 is "of interest"
    prompts = make_benchmark_prompts(views, gts)
    preds = method.segment(fitted, scene, prompts)
    names = [str(i) for i in range(len(views))]
    score = score_masks(dict(zip(names, preds)), dict(zip(names, gts)))
    assert score.miou > 0.8
    opreds, oclusters = method.segment_oracle(fitted, scene, gts)
    assert len(opreds) == len(views)
    assert len(oclusters) == 1
    # save / load round trip
    fitted.save(tmp_path / "out")
    back = FittedModel.load(tmp_path / "out", gm, deform, TraseSettings)
    assert np.array_equal(back.labels, fitted.labels) and back.stats["n_clusters"] == 2
    assert back.config == fitted.config  # the typed settings round trip
    assert (tmp_path / "out" / "point_cloud.ply").is_file()
    with pytest.raises(MethodError, match="not a fitted model directory"):
        FittedModel.load(tmp_path / "missing")


def test_missing_masks_is_a_user_error(tmp_path):
    gm, deform, _, views = tiny_scene(n_per=3)
    method = get_method("trase")
    cfg = _small_config(method)
    with pytest.raises(MethodError, match="masks of training view"):
        method.fit(_Scene(views, views), gm, deform, tmp_path, cfg, tmp_path / "fit", progress=False)


def test_filter_threshold_paper_values_one_value_on_cpu():
    m = TraseMethod()
    for key, thr in (("nerfds", 0.4), ("immersive", 0.6), ("hypernerf", 0.9), ("neu3d", 0.98)):
        assert m.settings("paper", key).filter_threshold == thr
        assert m.settings("cpu", key).filter_threshold == 0.7
        assert m.settings("cpu-v2", key).filter_threshold == 0.7  # an earlier geometry preset: the cpu tier
    assert m.settings("paper").filter_threshold == 0.9  # a capture of one's own


def test_trase_hard_has_its_own_cpu_clustering_and_the_paper_values_otherwise():
    hard, trase = get_method("trase-hard"), TraseMethod()
    for key in ("hypernerf", "neu3d"):
        cpu = hard.settings("cpu", key)
        assert (cpu.clustering.params["min_cluster_size"], cpu.filter_threshold) == (25, 0.6)  # chosen on seed 1
        same = lambda a: dataclasses.replace(a, features=dataclasses.replace(a.features, objective="x"))
        assert cpu.clustering.params["cluster_selection_epsilon"] == 0.01
        # only the objective differs, and the stopping rule chosen on TRASE's loss (its whole schedule)
        assert cpu.features.stop_interval == 0 and trase.settings("cpu", key).features.stop_interval == 250
        tr = trase.settings("cpu", key).features
        assert same(cpu).features == dataclasses.replace(same(trase.settings("cpu", key)).features, stop_interval=0)
        assert tr.stop_patience == cpu.features.stop_patience  # the rest as the class has it
        assert same(hard.settings("paper", key)) == same(trase.settings("paper", key))  # the paper's are the paper's
    assert get_method("trase-all").settings("cpu", "hypernerf").clustering.params["min_cluster_size"] == 50  # not chosen yet
    for name in ("trase-all", "cgc", "opengaussian"):
        assert get_method(name).settings("cpu", "hypernerf").features.stop_interval == 0, name


def test_cpu_preset_clustering_and_steps():
    m = TraseMethod()
    cpu, paper = m.settings("cpu", "hypernerf"), m.settings("paper", "hypernerf")
    assert cpu.clustering.params["min_cluster_size"] == 50
    assert (cpu.clustering.min_sample, paper.clustering.min_sample) == (15000, 5000)  # cpu: all
    assert paper.clustering.params == {"min_cluster_size": 10, "cluster_selection_epsilon": 0.01}
    assert cpu.features.iterations == 3000 and paper.features.iterations == 10000
    assert (cpu.features.n_pixels, paper.features.n_pixels) == (2000, 5000)  # Np capped on cpu
    assert (cpu.features.n_masks, paper.features.n_masks) == (25, 25)
    multi = m.settings("paper", "neu3d").features
    assert (multi.n_pixels, multi.n_masks) == (10000, 50)
    own = m.settings("paper", None, monocular=False).features
    assert (own.n_pixels, own.n_masks) == (10000, 50)
    assert paper.render_rule == "alone"  # the paper's rule


def test_a_clustering_parameter_no_algorithm_reads_is_refused_before_any_stage():
    from benchmark.config import ConfigError

    cfg = TraseMethod().settings("cpu", "hypernerf")
    TraseMethod().check_settings(cfg)
    cfg.clustering.params = {**cfg.clustering.params, "cluster_selection_method": "leaf"}
    with pytest.raises(ConfigError, match="method.clustering: clustering parameter 'cluster_selection_method'"):
        TraseMethod().check_settings(cfg)


def test_render_rule_visible_under_the_cpu_preset_on_a_monocular_rig_only():
    m = TraseMethod()
    rules = {(preset, mono): m.settings(preset, None, monocular=mono).render_rule
             for preset in ("cpu", "paper") for mono in (True, False)}
    assert rules == {("cpu", True): "visible", ("cpu", False): "alone",
                     ("paper", True): "alone", ("paper", False): "alone"}


def test_the_soft_correspondence_on_small_monocular_images_is_trases_own():
    from benchmark.methods.trase_method import with_objective
    from lazyspecs.presets import Context

    def params(method, monocular, size, objective=None):
        ctx = Context(dataset="nerfds" if monocular else "neu3d", monocular=monocular, image_size=size,
                      objective=objective)
        method = get_method(method) if isinstance(method, str) else method
        return method.resolve_settings("cpu", ctx).config.features.objective_params

    assert params("trase", True, (64, 48)) == {"correspondence": "jaccard"}
    assert params("trase", False, (48, 36)) == {}  # the multi-view tiny scenes lost under it
    assert params("trase", True, (160, 120)) == {}  # small scenes: not measured for it
    for name in ("trase-hard", "trase-all", "opengaussian"):  # chosen on TRASE's loss, not theirs
        assert params(name, True, (64, 48)) == {}, name
    assert params("cgc", True, (64, 48)) == {"min_mask_pixels": "auto"}
    assert params(with_objective("cgc"), True, (64, 48)) == {}
    assert params("trase", True, (64, 48), objective="cgc") == {}  # --set method.features.objective=cgc


def test_a_parameter_the_objective_does_not_take_stops_the_run_before_any_stage():
    from benchmark.config import ConfigError

    cfg = TraseMethod().settings("cpu", "hypernerf")
    cfg.features.objective, cfg.features.objective_params = "cgc", {"correspondence": "jaccard"}
    with pytest.raises(ConfigError, match="objective_params.correspondence: objective 'cgc' takes no such"):
        TraseMethod().check_settings(cfg)
    cfg.features.objective_params = {"min_mask_pixels": 12}
    TraseMethod().check_settings(cfg)
    cfg.features.objective, cfg.features.objective_params = "trase-hard", {"correspondence": "jaccard"}
    with pytest.raises(ConfigError, match="objective 'trase-hard' takes no such parameter"):
        TraseMethod().check_settings(cfg)


def test_each_click_is_lifted_in_its_own_frame(monkeypatch):
    # prompts from several test frames: a click is lifted with the camera of the frame it was
    # made in, not the first prompted frame's
    import types

    import trase.prompts as tp
    from benchmark.protocol.prompts import BenchmarkPrompts
    from trase.prompts import Click

    _, _, _, views = tiny_scene(n_per=2)
    seen = []
    monkeypatch.setattr(tp, "click_to_cluster", lambda g, d, camera, click, *a, **k: seen.append(camera.name) or 0)
    clicks = [Click(1.0, 1.0, views[0].name, views[0].camera.time, 0),
              Click(2.0, 2.0, views[2].name, views[2].camera.time, 2)]
    prompts = BenchmarkPrompts(0, views[0].name, views[0].camera.time, clicks)
    fitted = types.SimpleNamespace(gaussians=None, deformation=None, labels=np.zeros(4, int), features=None,
                                   config=TraseMethod().settings("cpu", "hypernerf"))
    assert TraseMethod().select(fitted, _Scene(train=views, test=views), prompts) == [0]
    assert seen == [views[0].camera.name, views[2].camera.name]


def test_the_base_class_fit_is_learn_then_group_and_has_no_oracle():
    from benchmark.methods import Method

    calls = []

    class Two(Method):
        def learn(self, scene, gaussians, deformation, masks_dir, config, work_dir, progress=True):
            calls.append("learn")
            return np.ones((3, 2), np.float32), {"timings": {"learn": 1.0}}

        def group(self, feats, config, gaussians=None, deformation=None, learn_info=None):
            calls.append("group")
            return FittedModel(feats, np.zeros(3, np.int64), np.ones(3, bool), learn_info["timings"], {}, config)

    fitted = Two().fit(None, None, None, Path("m"), {"k": 1}, Path("w"))
    assert calls == ["learn", "group"] and fitted.timings == {"learn": 1.0} and fitted.config == {"k": 1}
    assert Two().segment_oracle(fitted, None, []) is None  # no bound: evaluate records oracle None
