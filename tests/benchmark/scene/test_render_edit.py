"""render and edit on a tiny run: every mode, the camera paths, edit folders that reopen,
and one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmark.cli import main
from benchmark.scene.folders import open_scene_folder
from imagefiles import read_rgb8


@pytest.fixture(scope="module")
def run_dir(tiny_run):
    return tiny_run


def _frames(d):
    return sorted(d.glob("*.png"))


def test_render_every_mode_and_path(run_dir, tmp_path):
    folder = open_scene_folder(run_dir)
    n_test = len(folder.views)
    for mode in ("rgb", "depth", "clusters", "pca"):
        assert main(["render", "--run", str(run_dir), "--mode", mode, "--out", str(tmp_path), "--quiet",
                     "--no-mp4"]) == 0
        frames = _frames(tmp_path / mode)
        assert len(frames) == n_test and read_rgb8(frames[0]).max() > 0  # something is drawn
        assert (tmp_path / f"{mode}.webp").stat().st_size > 0
    assert main(["render", "--run", str(run_dir), "--cameras", "orbit", "--frames", "5", "--scale", "2",
                 "--out", str(tmp_path / "orbit"), "--quiet"]) == 0
    frames = _frames(tmp_path / "orbit" / "rgb")
    cam = folder.views[0][1]
    assert len(frames) == 5 and read_rgb8(frames[0]).shape == (2 * cam.height, 2 * cam.width, 3)
    assert (tmp_path / "orbit" / "rgb.mp4").stat().st_size > 0
    assert not np.array_equal(read_rgb8(frames[0]), read_rgb8(frames[-1]))  # the camera moved


def test_selection_mode_tints_the_selected_objects(run_dir, tmp_path):
    assert main(["render", "--run", str(run_dir), "--mode", "selection", "--selected", "--out", str(tmp_path),
                 "--quiet", "--no-mp4"]) == 0
    assert main(["render", "--run", str(run_dir), "--out", str(tmp_path), "--quiet", "--no-mp4"]) == 0
    sel = np.stack([read_rgb8(p) for p in _frames(tmp_path / "selection")])
    rgb = np.stack([read_rgb8(p) for p in _frames(tmp_path / "rgb")])
    changed = (sel != rgb).any(axis=-1)
    assert 0 < changed.mean() < 0.5  # the objects, not the whole picture


def test_edit_folders_reopen_and_chain(run_dir, tmp_path, capsys):
    base = open_scene_folder(run_dir)
    assert main(["edit", "remove", "--run", str(run_dir), "--selected", "--out", str(tmp_path / "rm")]) == 0
    assert "next: trase-bench render" in capsys.readouterr().out
    rec = json.loads((tmp_path / "rm" / "edit.json").read_text())
    assert rec["operation"] == "remove" and rec["params"]["clusters"] == sorted(base.selected)
    removed = open_scene_folder(tmp_path / "rm")
    n_sel = int(np.isin(base.model.labels, base.selected)[base.model.keep].sum())
    assert removed.kind == "edit" and removed.model.num_gaussians == base.model.num_gaussians - n_sel
    assert [n for n, _ in removed.views] == [n for n, _ in base.views]
    assert removed.model.gaussians.features is not None  # learned features travel with the edit
    assert main(["edit", "recolor", "--run", str(tmp_path / "rm"), "--clusters", "0", "--rgb", "1,0,0",
                 "--out", str(tmp_path / "red")]) == 0
    assert main(["edit", "compose", "--run", str(tmp_path / "rm"), "--from", str(run_dir), "--from-selected",
                 "--translate", "0,0,0.2", "--time-offset", "0.1", "--out", str(tmp_path / "comp")]) == 0
    comp = open_scene_folder(tmp_path / "comp")
    assert comp.model.num_gaussians == base.model.num_gaussians
    assert json.loads((tmp_path / "comp" / "edit.json").read_text())["motion"] == "table"
    assert main(["render", "--run", str(tmp_path / "comp"), "--frames", "2", "--quiet", "--no-mp4"]) == 0
    assert main(["edit", "extract", "--run", str(run_dir), "--selected", "--out", str(tmp_path / "obj"),
                 "--ply", str(tmp_path / "obj.ply"), "--time", "0.5"]) == 0
    assert open_scene_folder(tmp_path / "obj").model.num_gaussians == n_sel
    from trase.gaussians import GaussianModel

    assert GaussianModel.load_ply(tmp_path / "obj.ply").num_gaussians == n_sel


@pytest.mark.parametrize("args, message", [
    (["render", "--run", "{tmp}"], "not a run (results.json)"),
    (["render", "--run", "{run}", "--clusters", "999"], "no cluster 999"),
    (["render", "--run", "{run}", "--clusters", "a,b"], "expected cluster ids"),
    (["render", "--run", "{run}", "--click", "nosuchview:1,1"], "no view 'nosuchview'"),
    (["render", "--run", "{run}", "--click", "bad"], "expected VIEW:X,Y"),
    (["render", "--run", "{run}", "--cache", "{tmp}"], "not in the cache given"),
    (["edit", "remove", "--run", "{run}", "--out", "{tmp}/x"], "say what to edit"),
    (["edit", "remove", "--run", "{run}", "--mask", "cam/00:{tmp}/none.png", "--out", "{tmp}/x"], "not found"),
    (["edit", "compose", "--run", "{run}", "--from", "{run}", "--mask", "v:{tmp}", "--out", "{tmp}/x"], "compose: select"),
    (["edit", "recolor", "--run", "{run}", "--clusters", "0", "--out", "{tmp}/x"], "exactly one of --rgb"),
    (["edit", "recolor", "--run", "{run}", "--clusters", "0", "--rgb", "1,0", "--out", "{tmp}/x"], "expected 3 numbers"),
    (["edit", "recolor", "--run", "{run}", "--clusters", "0", "--rgb", "2,0,0", "--out", "{tmp}/x"], "in [0, 1]"),
    (["edit", "compose", "--run", "{run}", "--from", "{run}", "--out", "{tmp}/x"], "say which object"),
    (["edit", "remove", "--run", "{run}", "--selected", "--out", "{run}"], "must differ"),
])
def test_errors_are_one_line(run_dir, tmp_path, capsys, args, message):
    argv = [a.format(run=run_dir, tmp=tmp_path) for a in args]
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x").exists()


def test_report_carries_a_clip_of_the_selection(run_dir):
    from benchmark.results.report import make_report
    from benchmark.scene.render import selection_clip

    page = make_report(run_dir, selection_clip).read_text()
    assert page.count("data:image/webp;base64") == 1 and "No clip" not in page
    assert (run_dir / "report" / "clip.webp").stat().st_size > 0


def test_edit_style_with_local_weights(run_dir, tmp_path, capsys):
    import cv2
    import torch

    from trase.edit.style import VGG16Features

    style = tmp_path / "style.png"
    cv2.imwrite(str(style), np.tile(np.array([[[0, 200, 255]], [[30, 30, 30]]], np.uint8), (8, 16, 1)))
    args = ["edit", "style", "--run", str(run_dir), "--selected", "--style", str(style), "--out", str(tmp_path / "s"),
            "--iterations", "3", "--quiet"]
    assert main(args) == 1 and "needs VGG-16 weights" in capsys.readouterr().err
    torch.manual_seed(0)
    torch.save(VGG16Features().state_dict(), tmp_path / "vgg.pth")
    assert main([*args, "--vgg", str(tmp_path / "vgg.pth")]) == 0
    rec = json.loads((tmp_path / "s" / "edit.json").read_text())
    assert rec["operation"] == "style" and rec["params"]["iterations"] == 3
    styled, base = open_scene_folder(tmp_path / "s").model, open_scene_folder(run_dir).model
    assert styled.num_gaussians == base.num_gaussians
    assert not torch.equal(styled.gaussians.sh_dc, base.gaussians.sh_dc)


def test_folders_render_with_the_near_plane_their_geometry_trained_with(run_dir, tmp_path):
    """A run's folder gives its views the near plane of its reconstruction (here written into a
    copy of the tiny run's record); orbits and the viewer's cameras keep it."""
    import shutil

    from benchmark.scene.viewer import camera_from_view
    from trase.visualize import look_centre, orbit_cameras

    assert open_scene_folder(run_dir).near == 0.01  # ground-truth geometry: the cameras' default
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    rec = json.loads((copy / "results.json").read_text())
    rec["config"]["geometry"] = {**rec["config"]["geometry"], "source": "reconstruct",
                                 "train": {**rec["config"]["geometry"].get("train", {}), "near_plane": 0.2}}
    (copy / "results.json").write_text(json.dumps(rec))
    cache = next(p / ".cache" for p in run_dir.parents if (p / ".cache").is_dir())
    far = open_scene_folder(copy, cache)
    assert far.near == 0.2 and {c.near for _, c in far.views} == {0.2}
    cams = [c for _, c in far.views]
    assert {c.near for c in orbit_cameras(cams[0], look_centre(cams), 3)} == {0.2}
    assert camera_from_view(np.eye(3), np.zeros(3), 1.0, 4 / 3, 120, 0.5, far.near).near == 0.2
    assert camera_from_view(np.eye(3), np.zeros(3), 1.0, 4 / 3, 120, 0.5).near == 0.01


def test_a_click_on_a_selected_cluster_follows_the_runs_on_selected(run_dir):
    """--click on a cluster already chosen by --clusters: nothing more under "nothing", the
    cluster ranked next under the pixel under "next" (trase.prompts.ON_SELECTED)."""
    from benchmark.scene.folders import resolve_selection
    from trase.edit import by_click

    folder = open_scene_folder(run_dir)
    name, cam = folder.views[0]

    def cluster_under(x, y, exclude=()) -> int:
        return by_click(folder.model, cam, x + 0.5, y + 0.5, rule=folder.click_rule, exclude=exclude)[0]

    pixels = ((x, y, k) for y in range(cam.height) for x in range(cam.width) if (k := cluster_under(x, y)) >= 0)
    # the first pixel where a second cluster is drawn under the first
    found = next(((x, y, k, o) for x, y, k in pixels if (o := cluster_under(x, y, {k})) >= 0), None)
    assert found is not None, "no pixel with two clusters under it"
    x, y, k, other = found
    click = (f"{name}:{x},{y}",)
    folder.on_selected = "nothing"
    assert resolve_selection(folder, clusters=str(k), clicks=click)[0] == [k]
    folder.on_selected = "next"
    assert resolve_selection(folder, clusters=str(k), clicks=click)[0] == sorted({k, other})
