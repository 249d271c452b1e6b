"""The corrective protocol in a run: a stand-in method whose clusters are label maps, so that
what the robot user clicks and what each click selects can be worked out by hand."""

import dataclasses
import types

import numpy as np
import pytest

from benchmark.pipeline.corrective import Predictor, correct, score_curve
from benchmark.pipeline.settings import PromptProtocol
from trase.prompts import Click

# one test frame, 8 x 8, the object of interest rows 1-6, columns 1-4 (24 px). WALL: cluster 1 is
# the object but for a wall (3, rows 3-4, columns 3-7) that covers 4 of its pixels and 6 beside it.
# SPLIT: the object is clusters 1 (columns 1-2) and 2 (columns 3-4)
GT = np.zeros((8, 8), bool)
GT[1:7, 1:5] = True
WALL = np.where(GT, 1, 0)
WALL[3:5, 3:8] = 3
SPLIT = np.where(GT, 1, 0)
SPLIT[1:7, 3:5] = 2


@dataclasses.dataclass
class Scene:
    test: list
    gt_masks: list


class LabelMethod:
    """Clusters are a label map's values; a click selects the label under it; a selection
    renders as the pixels of its labels (in every view the same map)."""

    name = "labels"
    selects_clusters = True

    def __init__(self, labels: np.ndarray, negative_clicks: bool) -> None:
        self.labels, self.negative_clicks = labels, negative_clicks
        self.renders = 0

    def click_clusters(self, fitted, scene, prompts):
        return [int(self.labels[int(c.v), int(c.u)]) for c in prompts.clicks]

    def render_selection(self, fitted, scene, clusters):
        self.renders += 1
        return [np.isin(self.labels, [k for k in clusters if k > 0]) for _ in scene.test]


def _run(labels: np.ndarray, negative_clicks: bool, corrections: int = 3):
    from benchmark.protocol.prompts import BenchmarkPrompts

    method = LabelMethod(labels, negative_clicks)
    fitted = types.SimpleNamespace(gaussians=object(), stats={})
    camera = types.SimpleNamespace(height=8, width=8)
    scene = Scene([types.SimpleNamespace(name=n, camera=camera) for n in ("f0", "f1")], ["gt0", "gt1"])
    first = [Click(1.5, 3.5, "f0", 0.0, 0)] if labels is SPLIT else [Click(3.5, 3.5, "f0", 0.0, 0)]
    predictor = Predictor(method, fitted, scene, BenchmarkPrompts(0, "f0", 0.0, first, "test"))
    run = correct(predictor, first, [GT, GT], PromptProtocol(corrections=corrections, correction_target=0.9))
    summary, final = score_curve(predictor, run, ["00000", "00001"], [GT, GT])
    return method, run, summary, final


def test_a_missed_part_gets_a_positive_click_and_noc_counts_the_clicks_to_reach_the_target():
    method, run, summary, (preds, selected, per_click) = _run(SPLIT, negative_clicks=True)
    assert per_click == [1, 2] and selected == [1, 2] and np.array_equal(preds[1], GT)
    assert [p["miou"] for p in summary["curve"]] == [0.5, 1.0]  # stopped: the click frame reached 0.9
    assert summary["noc@85"] == summary["noc@90"] == 2 and run.budget == 3
    assert summary["check_frames"] == ["f1"]  # the one other test frame, watched beside the click frame
    assert method.renders == 2 + 2  # each selection once at the click frame, once at every frame


def test_the_wall_gets_a_negative_click_and_a_later_click_on_it_cannot_bring_it_back():
    _, run, summary, (_, selected, per_click) = _run(WALL, negative_clicks=True)
    # the wall (10 px, 4 inside) -> the object's missed part (+1) -> the wall outside (-3) -> the
    # wall's inside part, where the first click was: the wall is ruled out, the click chooses
    # nothing and changes nothing: undone; budget spent
    assert [c.positive for c in run.clicks] == [True, True, False] and [k for _, k in run.spent] == [True, True, False]
    assert run.spent[2][0] == run.clicks[0] and per_click == [3, 1, 3] and selected == [1]
    assert [round(p["miou"], 3) for p in summary["curve"]] == [0.133, 0.8, 0.833, 0.833]
    assert summary["curve"][3]["undone"] and [c["n"] for c in summary["undone"]] == [4]
    assert summary["noc@85"] == summary["noc@90"] == 1 + 3 + 1  # never reached: first + budget + 1
    assert [c["positive"] for c in summary["corrections"] if "positive" in c] == [False]


def test_a_method_without_negative_clicks_gets_positive_corrections_only():
    _, run, summary, (_, selected, _) = _run(WALL, negative_clicks=False)
    assert all(c.positive for c in run.clicks) and len(run.clicks) == 2  # nothing missed is left
    assert selected == [1, 3] and summary["negatives"] is False and summary["noc@85"] == 5


def test_no_corrections_leaves_the_first_clicks():
    _, run, summary, _ = _run(WALL, negative_clicks=True, corrections=0)
    assert len(run.clicks) == 1 and len(summary["curve"]) == 1 and summary["noc@85"] == 2


def test_the_protocols_settings_are_checked():
    from benchmark.config import ConfigError

    with pytest.raises(ConfigError, match="prompts.corrections=-1"):
        PromptProtocol(corrections=-1)
    with pytest.raises(ConfigError, match="correction_target=1.5"):
        PromptProtocol(correction_target=1.5)
    with pytest.raises(ConfigError, match="correction_check_frames=-2"):
        PromptProtocol(correction_check_frames=-2)
    with pytest.raises(ConfigError, match="correction_undone_radius=-1"):
        PromptProtocol(correction_undone_radius=-1)
    with pytest.raises(ConfigError, match="correction_region_tries=1.5"):
        PromptProtocol(correction_region_tries=1.5)


def test_masks_of_another_count_or_size_are_named_errors():
    from benchmark.methods import MethodError
    from benchmark.protocol.prompts import BenchmarkPrompts

    method = LabelMethod(SPLIT, negative_clicks=True)
    camera = types.SimpleNamespace(height=6, width=8)  # the method renders 8 x 8
    scene = Scene([types.SimpleNamespace(name="f0", camera=camera)], ["gt0"])
    prompts = BenchmarkPrompts(0, "f0", 0.0, [Click(1.5, 3.5, "f0", 0.0, 0)], "test")
    with pytest.raises(MethodError, match=r"labels gave a \(8, 8\) mask for test view f0 \(6 x 8\)"):
        Predictor(method, types.SimpleNamespace(gaussians=object(), stats={}), scene, prompts).masks(prompts.clicks)


@pytest.mark.parametrize("name, value", [("corrections", 5), ("correction_target", 0.85), ("correction_min_gain", 0.01),
                                         ("correction_check_frames", 0), ("correction_undone_radius", 3.0)])
def test_every_setting_that_changes_the_robots_clicks_changes_the_evaluate_key(name, value):
    """A cached evaluate stage is reused only where the robot user would click the same."""
    from benchmark.pipeline.evaluate import prompt_key

    base = PromptProtocol(correction_undone_radius=2.0, correction_region_tries=2)
    assert dataclasses.replace(base, **{name: value}) != base
    assert prompt_key(dataclasses.replace(base, **{name: value})) != prompt_key(base)


def test_region_tries_enter_the_key_only_where_a_radius_makes_them_act():
    from benchmark.pipeline.evaluate import prompt_key

    with_radius = PromptProtocol(correction_undone_radius=2.0, correction_region_tries=0)
    assert prompt_key(dataclasses.replace(with_radius, correction_region_tries=2)) != prompt_key(with_radius)
    without = PromptProtocol(correction_undone_radius=0.0, correction_region_tries=0)
    assert prompt_key(dataclasses.replace(without, correction_region_tries=2)) == prompt_key(without)
    assert "undone_radius" not in prompt_key(without)["corrective"]  # runs without retries keep their keys
    assert prompt_key(PromptProtocol(corrections=0)) == {}
