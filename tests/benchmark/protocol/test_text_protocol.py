"""The text protocol: phrases from prompts_text.json, the ground-truth stand-ins, and a run on
the tiny scene that reads text instead of clicks."""

import json

import numpy as np
import pytest

from benchmark.errors import UserError
from benchmark.protocol.text import _TruthModel, phrases_for_objects, read_phrases, scene_phrases


def test_phrases_file_errors_name_the_file(tmp_path):
    path = tmp_path / "prompts_text.json"
    with pytest.raises(UserError, match=r"prompts_text.json: no text prompts file"):
        read_phrases(path, "cup")
    path.write_text("{not json")
    with pytest.raises(UserError, match=r"prompts_text.json: not readable JSON"):
        read_phrases(path, "cup")
    path.write_text(json.dumps({"americano": ["the cup", " "]}))
    with pytest.raises(UserError, match=r"no phrases for sequence 'americano' \(expected a list of non-empty strings\)"):
        read_phrases(path, "americano")
    path.write_text(json.dumps({"synthetic-tiny": ["the  ball"]}))
    assert read_phrases(path, "synthetic", aliases=("synthetic-tiny",)) == ["the ball"]


def test_the_stand_ins_find_the_named_object_and_only_it(tiny_scene):
    truth = tiny_scene.truth
    view = tiny_scene.test[0].name
    model = _TruthModel(truth, view)
    ball = next(o.id for o in truth.objects if o.name == "ball")
    (det,) = model.detect(None, "The ball")
    mask = model.segment(None, det.box)
    assert np.array_equal(mask, model.ids == ball)
    assert det.score == pytest.approx(float((model.ids == ball).mean()))
    assert model.detect(None, "a unicorn") == []


def test_a_generated_scene_holds_its_phrases(tiny_scene):
    phrases, source = scene_phrases(type("P", (), {"text_file": ""})(), tiny_scene)
    names = [o.name for o in tiny_scene.truth.objects if o.of_interest]
    assert phrases == phrases_for_objects(names) and source.endswith("prompts_text.json")


def test_a_run_under_the_text_protocol_records_each_phrase_and_its_label(tiny_run):
    from benchmark.cli import main
    from benchmark.results.runs import load_run, protocol

    out = tiny_run.parents[3]
    args = ["run", "--method", "trase", "--dataset", "hypernerf", "--sequence", "synthetic", "--data-root",
            str(out.parent), "--runs", str(out), "--quiet", "--set", "geometry.source=ground-truth",
            "--set", "method.features.iterations=40", "--set", "method.features.n_pixels=400",
            "--set", "prompts.source=text", "--set", "prompts.text_detector=ground-truth",
            "--set", "prompts.text_segmenter=ground-truth", "--name", "text"]
    assert main(args) == 0
    rec = load_run(out / "trase/hypernerf/synthetic/text/results.json")
    text = rec["text"]
    assert [p["phrase"] for p in text["phrases"]] == ["the ball", "the ring", "the blob"]
    chosen = sorted({k for p in text["phrases"] for k in p["clusters"]})
    assert rec["selected_clusters"] == chosen and rec["click_sets"] is None and rec["corrective"] is None
    assert all(p["view"] and p["mask_pixels"] > 0 for p in text["phrases"])
    label = protocol(rec)["prompts"]
    assert label == "text (ground-truth boxes, ground-truth masks, lifted by the clusters of best IoU)"
    clicks = load_run(tiny_run / "results.json")
    assert rec["oracle"]["miou"] == pytest.approx(clicks["oracle"]["miou"])  # the same fit under either protocol


def test_a_method_that_selects_no_clusters_is_told_so():
    from benchmark.pipeline.text_prompts import segment_text

    method = type("M", (), {"name": "sa4d", "selects_clusters": False})()
    with pytest.raises(UserError, match=r"sa4d: prompts.source=text lifts masks to clusters; this method selects none"):
        segment_text(method, type("F", (), {"gaussians": object()})(), None, None)


def test_ground_truth_stand_ins_need_a_synthetic_scene():
    from benchmark.protocol.settings import PromptProtocol
    from benchmark.protocol.text import TextModel

    scene = type("S", (), {"truth": None, "dataset": "hypernerf", "sequence": "americano"})()
    with pytest.raises(UserError, match=r"only synthetic scenes have ground truth \(hypernerf/americano has none\)"):
        TextModel(PromptProtocol(source="text", text_detector="ground-truth"), scene)
