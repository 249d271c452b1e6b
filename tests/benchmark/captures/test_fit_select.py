"""``trase-bench fit`` and ``select`` on captures of one's own: config, masks made elsewhere,
the exported folder, clicks, errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import masks as masklib
from benchmark.captures import CaptureOptions, load_capture
from benchmark.captures.fit import FitOptions, fit_capture, monocular, next_steps
from benchmark.captures.select import mask_for_view, parse_click, parse_mask, select_clicks
from benchmark.config import ConfigError, parse_overrides
from benchmark.errors import UserError
from benchmark.methods import get_method
from benchmark.pipeline.masks import masks_from_files
from benchmark.results.runs import find_runs
from tests.benchmark.settings_helpers import capture_dict

FAST = ["geometry.train.iterations=60", "method.features.iterations=40"]


def test_capture_config_follows_the_rig_and_checks_the_capture_section():
    m = get_method("trase")
    mono = capture_dict(m, True, CaptureOptions().to_dict(), {})
    multi = capture_dict(m, False, CaptureOptions().to_dict(), parse_overrides(["preset=paper"]))
    assert (mono["method"]["features"]["n_masks"], multi["method"]["features"]["n_masks"]) == (25, 50)
    assert multi["method"]["features"]["n_pixels"] == 10000 and multi["method"]["filter_threshold"] == 0.9
    # Deformable-3DGS's own schedule under the paper preset (no benchmark's per-dataset one)
    assert (multi["geometry"]["train"]["warm_up"], multi["geometry"]["train"]["densify_until"]) == (3000, 15000)
    assert mono["masks"] == {"generator": "classical", "checkpoint": None, "seed": 0, "dir": None}
    assert "prompts" not in mono and mono["capture"]["holdout"] == "none"
    with pytest.raises(ConfigError, match="--set capture.nope: unknown setting"):
        capture_dict(m, True, CaptureOptions().to_dict(), parse_overrides(["capture.nope=1"]))


def test_monocular_is_one_view_per_time(tiny_scene, capture_dirs):
    assert monocular(load_capture(capture_dirs["colmap"]))
    static = load_capture(capture_dirs["colmap"], CaptureOptions(time="static"))
    assert not monocular(static)  # six views at one time: a rig


def test_masks_made_elsewhere_are_found_by_view_or_image_name(tiny_scene, tmp_path):
    views = tiny_scene.train
    from masks.generators import make_generator

    gen = masklib.generate_scene_masks(views, make_generator("classical"), tmp_path / "made", progress=False)
    src = tmp_path / "src"
    src.mkdir()
    shutil.copy(gen[0], masklib.mask_path(src, views[0].name))  # by view name
    shutil.copy(gen[1], masklib.mask_path(src, Path(views[1].image_path).stem + "x"))  # wrong name
    with pytest.raises(ConfigError, match=f"no masks for training view {views[1].name} in masks.dir"):
        masks_from_files(views, src, tmp_path / "out")
    shutil.copy(gen[1], masklib.mask_path(src, Path(views[1].image_path).stem))  # by image stem
    shutil.copy(gen[2], masklib.mask_path(src, views[2].name))
    out = masks_from_files(views, src, tmp_path / "out")
    for a, b in zip(gen, out):
        assert np.array_equal(masklib.load(a).masks, masklib.load(b).masks)


def test_masks_made_elsewhere_are_found_by_camera_folder_of_a_multi_camera_capture(tiny_scene, tmp_path):
    """A transforms capture names its views images/cam01/00001; masks stored for the view
    cam01/00001 (what a multi-view scene's mask folder holds) are found, and a view with none
    names every place looked at."""
    from benchmark.datasets.scene import View
    from masks.generators import make_generator

    gen = masklib.generate_scene_masks(tiny_scene.train[:1], make_generator("classical"), tmp_path / "made",
                                       progress=False)
    cap = tmp_path / "cap" / "images" / "cam01"
    cap.mkdir(parents=True)
    image = cap / "00001.png"
    shutil.copy(tiny_scene.train[0].image_path, image)
    view = View(name="images/cam01/00001", camera=tiny_scene.train[0].camera, image_path=image, frame=0)
    src = tmp_path / "src"
    with pytest.raises(ConfigError, match=r"src/images__cam01__00001.masks: no masks for training view "
                                          r"images/cam01/00001 in masks.dir \(nor cam01__00001.masks, "
                                          r"00001.masks, 00001.pt\)"):
        masks_from_files([view], src, tmp_path / "out")
    src.mkdir()
    shutil.copy(gen[0], masklib.mask_path(src, "cam01/00001"))
    out = masks_from_files([view], src, tmp_path / "out")
    assert np.array_equal(masklib.load(out[0]).masks, masklib.load(gen[0]).masks)


def test_fit_refuses_what_it_cannot_read(tmp_path):
    with pytest.raises(UserError, match="no known capture layout"):
        fit_capture(FitOptions(tmp_path, progress=False))
    with pytest.raises(UserError, match="--set capture.time"):
        fit_capture(FitOptions(tmp_path, overrides=["capture.time=later"], progress=False))


def test_click_parsing():
    assert parse_click("images/000002:12,7") == ("images/000002", 12.0, 7.0)
    for bad in ("000002", "000002:1", "000002:a,b", ":1,2"):
        with pytest.raises(UserError, match="expected VIEW:X,Y"):
            parse_click(bad)


def test_mask_prompt_parsing_and_reading(tmp_path):
    import cv2

    m = np.zeros((20, 40), np.uint8)
    m[4:14, 10:30] = 255
    path = tmp_path / "a:b.png"  # a ':' in the path too
    cv2.imwrite(str(path), m)
    assert parse_mask(f"images/000002:{path}") == ("images/000002", path)
    with pytest.raises(UserError, match="expected VIEW:PATH"):
        parse_mask("000002")
    with pytest.raises(UserError, match="not found"):
        parse_mask("000002:nothere.png")
    assert np.array_equal(mask_for_view(path, 40, 20), m > 0)
    half = mask_for_view(path, 20, 10)  # the view's aspect ratio: scaled, area filter
    assert np.array_equal(half, m[::2, ::2] > 0)
    with pytest.raises(UserError, match="another aspect ratio"):
        mask_for_view(path, 40, 40)
    cv2.imwrite(str(tmp_path / "empty.png"), np.zeros((20, 40), np.uint8))
    with pytest.raises(UserError, match="empty"):
        mask_for_view(tmp_path / "empty.png", 40, 20)
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(UserError, match="bad.png: cannot decode"):
        mask_for_view(tmp_path / "bad.png", 40, 20)


@pytest.mark.slow
def test_fit_exports_a_folder_that_select_reads(capture_dirs, tmp_path):
    out = tmp_path / "fit"
    fit_json = fit_capture(FitOptions(capture_dirs["nerfies"], out, holdout="every:2", overrides=FAST,
                                      cache_dir=tmp_path / "cache", progress=False))
    rec = json.loads(fit_json.read_text())
    assert rec["kind"] == "capture-fit" and rec["format"] == "nerfies" and rec["views"] == {"train": 2, "test": 2, "validation": 0}
    assert rec["holdout_psnr"] is not None and np.isfinite(rec["holdout_psnr"])
    assert set(rec["stages"]) == {"masks", "geometry", "features", "fit"}
    assert any("ignored 2 image(s)" in n for n in rec["notices"])
    for name in ("model", "segmentation/features.npy", "segmentation/point_cloud.ply", "views.json", *rec["previews"]):
        assert (out / name).exists(), name
    from trase.checkpoint import load_model

    g, _ = load_model(out / "model")
    assert g.num_gaussians == rec["n_gaussians"]
    assert find_runs(tmp_path) == []  # a fitted capture is never a benchmark result
    steps = next_steps(fit_json)
    assert any("trase-bench select --fit" in line and "--mask" in line for line in steps)
    assert any(f"trase-bench view --run {out}" in line for line in steps)
    from benchmark.scene.folders import open_scene_folder

    folder = open_scene_folder(out)  # what render, edit and view open
    assert folder.kind == "fit" and len(folder.views) == 4 and folder.model.num_gaussians == rec["n_gaussians"]
    # a rerun reuses every stage
    again = json.loads(fit_capture(FitOptions(capture_dirs["nerfies"], out, holdout="every:2", overrides=FAST,
                                              cache_dir=tmp_path / "cache", progress=False)).read_text())
    assert all(s["skipped"] for s in again["stages"].values())

    views = json.loads((out / "views.json").read_text())
    v = views["train"][0]
    res = select_clicks(out, [f"{v['name']}:{v['camera']['width'] // 2},{v['camera']['height'] // 2}"])
    assert len(res["masks"]) == 4 and (out / "selection" / "selection.json").is_file()
    assert sorted(p.name for p in (out / "selection").glob("*.png")) == sorted(f"{n}.png" for n in res["masks"])
    # a cluster's own mask in a view, as a mask prompt, chooses it
    from benchmark.captures.select import fitted_capture
    from imagefiles import png_bytes

    _, method, fitted, scene = fitted_capture(out)
    names = [w.name for w in scene.test]
    sizes = {k: int(method.render_selection(fitted, scene, [k])[names.index(v["name"])].sum())
             for k in np.unique(fitted.labels).tolist()}
    k = max(sizes, key=sizes.get)
    assert sizes[k] > 0
    (tmp_path / "object.png").write_bytes(png_bytes(
        method.render_selection(fitted, scene, [k])[names.index(v["name"])].astype(np.uint8) * 255))
    by_mask = select_clicks(out, [], tmp_path / "by-mask", masks=[f"{v['name']}:{tmp_path / 'object.png'}"])
    assert k in by_mask["per_mask"][0] and by_mask["clusters"] == by_mask["per_mask"][0]
    assert (tmp_path / "by-mask" / "selection.json").is_file()
    # a negative click at the pixel of a click keeps that click's cluster out: the click picks another or none
    from benchmark.protocol.prompts import interior_points

    (u, w), = interior_points(method.render_selection(fitted, scene, [k])[names.index(v["name"])], 1)[:1]
    on_k = f"{v['name']}:{int(u)},{int(w)}"
    (first,) = select_clicks(out, [on_k], tmp_path / "clicked")["per_click"]
    unclicked = select_clicks(out, [on_k], tmp_path / "unclicked", unclicks=[on_k])
    assert first >= 0 and unclicked["per_click"][0] == first and unclicked["per_click"][1] != first
    assert first not in unclicked["clusters"]
    with pytest.raises(UserError, match="--unclick .*pixel outside"):
        select_clicks(out, [on_k], tmp_path / "bad", unclicks=[f"{v['name']}:10000,1"])
    with pytest.raises(UserError, match="at least one --click VIEW:X,Y, --mask VIEW:PATH or --text PHRASE"):
        select_clicks(out, [])
    _a_phrase_selects_what_its_mask_covers(out, v["name"], method, fitted, scene, k, by_mask["clusters"], tmp_path)
    with pytest.raises(UserError, match="pixel outside"):
        select_clicks(out, [f"{v['name']}:10000,1"])
    with pytest.raises(UserError, match="not a fitted capture"):
        select_clicks(tmp_path, [f"{v['name']}:1,1"])


def _a_phrase_selects_what_its_mask_covers(out, view, method, fitted, scene, k, clusters, tmp_path):
    """A phrase whose detector box and mask are cluster ``k``'s selects what that mask does,
    recorded with its view and rule."""
    from benchmark.protocol.text_request import TextRequest
    from masks.text import Detection, TextSegmenter

    names = [w.name for w in scene.test]
    object_mask = method.render_selection(fitted, scene, [k])[names.index(view)]
    rows, cols = np.nonzero(object_mask)
    box = (float(cols.min()), float(rows.min()), float(cols.max() + 1), float(rows.max() + 1))
    stand_in = type("StandIn", (), {"detect": lambda self, image, phrase: [Detection(box, 0.9)],
                                    "segment": lambda self, image, b: object_mask})()
    request = TextRequest(("the object",), view=view)
    object.__setattr__(request, "load_segmenter", lambda: TextSegmenter(stand_in, stand_in))  # the models' stand-in
    by_text = select_clicks(out, [], tmp_path / "by-text", text=request)
    assert by_text["clusters"] == clusters
    (recorded,) = json.loads((tmp_path / "by-text" / "selection.json").read_text())["text"]
    assert recorded["view"] == view and recorded["clusters"] == clusters and recorded["rule"] == "iou"


@pytest.mark.slow
def test_a_motionless_capture_fits_as_plain_3dgs_and_selects(capture_dirs, tmp_path):
    out = tmp_path / "fit"
    fit_json = fit_capture(FitOptions(capture_dirs["colmap"], out, holdout="every:3",
                                      overrides=[*FAST, "capture.time=static"], cache_dir=tmp_path / "cache",
                                      progress=False))
    rec = json.loads(fit_json.read_text())
    assert any("motionless capture, reconstructed as plain 3DGS" in n for n in rec["notices"])
    assert rec["stages"]["geometry"]["info"]["motion"].startswith("static")
    from trase.checkpoint import load_model

    g, d = load_model(out / "model")
    assert d is None and g.num_gaussians == rec["n_gaussians"]
    views = json.loads((out / "views.json").read_text())
    v = views["train"][0]
    res = select_clicks(out, [f"{v['name']}:{v['camera']['width'] // 2},{v['camera']['height'] // 2}"])
    assert all(m.shape == (v["camera"]["height"], v["camera"]["width"]) for m in res["masks"].values())
