"""Text prompts where users meet them (edit, the viewer) on the tiny run, with the ground-truth
stand-ins in place of the downloaded models."""

import json

from benchmark.protocol.text import _TruthModel
from benchmark.protocol.text_request import TextRequest
from benchmark.scene.folders import EDIT_FILE
from masks.text import TextSegmenter


def _truth(run_dir, view):
    from benchmark.datasets.truth import find_truth

    rec = json.loads((run_dir / "results.json").read_text())
    model = _TruthModel(find_truth(__import__("pathlib").Path(rec["scene_dir"])), view)
    return TextSegmenter(model, model, min_score=0.0)


def test_edit_extract_by_text_keeps_the_named_object(tiny_run, tmp_path, monkeypatch):
    from benchmark.cli import main

    view = json.loads((tiny_run / "results.json").read_text())["frames"][0]["view"]
    monkeypatch.setattr(TextRequest, "load_segmenter", lambda self: _truth(tiny_run, view))
    out = tmp_path / "ball"
    assert main(["edit", "extract", "--run", str(tiny_run), "--text", "the ball", "--text-view", view,
                 "--mask-rule", "share", "--out", str(out)]) == 0
    rec = json.loads((out / EDIT_FILE).read_text())
    assert 0 < rec["n_gaussians"]["after"] < rec["n_gaussians"]["before"]
    assert rec["params"]["text"][0] | {"clusters": None} == {
        "phrase": "the ball", "view": view, "rule": "share", "clusters": None} | {
        k: rec["params"]["text"][0][k] for k in ("box", "score", "mask_pixels")}


def test_a_phrase_that_matches_nothing_is_one_line(tiny_run, tmp_path, monkeypatch, capsys):
    from benchmark.cli import main

    view = json.loads((tiny_run / "results.json").read_text())["frames"][0]["view"]
    monkeypatch.setattr(TextRequest, "load_segmenter", lambda self: _truth(tiny_run, view))
    code = main(["edit", "remove", "--run", str(tiny_run), "--text", "a unicorn", "--text-view", view,
                 "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code != 0 and "--text 'a unicorn': nothing matches in view(s)" in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_the_viewer_selects_by_text_in_the_current_view(tiny_run):
    from benchmark.scene.folders import open_scene_folder
    from benchmark.scene.viewer import SceneViewer
    from tests.benchmark.scene.test_viewer import _free_port

    folder = open_scene_folder(tiny_run)
    viewer = SceneViewer(folder, port=_free_port())
    try:
        home = folder.views[len(folder.views) // 2][0]
        viewer.segmenter = _truth(tiny_run, home)
        viewer.select_text()
        assert "type a phrase" in viewer.gui_status.content
        viewer.gui_text.value = "the ring"
        viewer.select_text()
        assert viewer.clusters, viewer.gui_status.content
        assert "text 'the ring': view the current view" in viewer.gui_status.content
    finally:
        viewer.close()
