"""A command method's input folder and output masks (benchmark.methods.command_io) on the
tiny synthetic HyperNeRF-format scene: the scene linked without its ground truth, the masks in
the public code's format, cameras, clicks; masks read back with one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

import masks as masklib
from benchmark.methods.command import CommandError
from benchmark.methods.command_io import frame_names, mask_files, read_outputs, write_inputs
from benchmark.protocol.prompts import make_benchmark_prompts
from benchmark.scoring import read_mask


@pytest.fixture(scope="module")
def written(tiny_scene, tmp_path_factory):
    """(scene, the masks written per training view, prompts, the input folder)."""
    root = tmp_path_factory.mktemp("command-io")
    rng = np.random.default_rng(0)
    sets = {}
    for v in tiny_scene.train:
        ms = masklib.MaskSet.from_masks(rng.random((4, v.camera.height, v.camera.width)) > 0.5)
        masklib.save(masklib.mask_path(root / "masks", v.name), ms)
        sets[v.name] = ms
    prompts = make_benchmark_prompts(tiny_scene.test, [read_mask(p) for p in tiny_scene.gt_masks])
    info = write_inputs(tiny_scene, "hypernerf", root / "masks", prompts, root / "input")
    return tiny_scene, sets, prompts, root / "input", info


def test_the_scene_is_linked_without_its_ground_truth(written):
    scene, _, _, inp, info = written
    linked = sorted(p.name for p in (inp / "scene").iterdir() if p.is_symlink())
    assert linked == info["linked"] and {"camera", "dataset.json", "rgb", "scene.json"} <= set(linked)
    assert "gt_masks" not in linked and "synthetic" not in linked  # the truth's folder
    for name in linked:  # links, never copies
        assert (inp / "scene" / name).resolve() == (Path(scene.root) / name).resolve()
    assert (Path(scene.root) / "gt_masks").is_dir() and (Path(scene.root) / "synthetic").is_dir()


def test_masks_are_in_the_public_format_under_image_stems(written):
    import torch

    scene, sets, _, inp, info = written
    files = mask_files(scene.train)
    assert files == [f"scene/masks/{Path(v.image_path).stem}.pt" for v in scene.train]
    for v, rel in zip(scene.train, files):
        obj = torch.load(inp / rel, weights_only=False)
        assert set(obj) == {"masks", "N", "H", "W"} and (obj["H"], obj["W"]) == (v.camera.height, v.camera.width)
        back = masklib.load(inp / rel)
        assert back.info["source_format"] == "official" and np.array_equal(back.masks, sets[v.name].masks)
    assert info["masks_bytes"] == sum((inp / f).stat().st_size for f in files)


def test_mask_files_of_images_sharing_a_stem_use_view_names():
    class V:
        def __init__(self, name, path):
            self.name, self.image_path = name, Path(path)

    views = [V("cam00/00001", "images/cam00/00001.png"), V("cam01/00001", "images/cam01/00001.png")]
    assert mask_files(views) == ["scene/masks/cam00/00001.pt", "scene/masks/cam01/00001.pt"]


def test_cameras_list_training_and_test_views_in_order(written):
    scene, _, _, inp, _ = written
    doc = json.loads((inp / "cameras.json").read_text())
    assert (doc["dataset"], doc["sequence"], doc["variant"], doc["version"]) == \
        ("hypernerf", scene.sequence, "synthetic", 1)
    assert [t["view"] for t in doc["train"]] == [v.name for v in scene.train]
    assert [t["frame"] for t in doc["test"]] == frame_names(len(scene.test)) == [p.stem for p in scene.gt_masks]
    for entry, v in zip(doc["train"] + doc["test"], scene.train + scene.test):
        cam = entry["camera"]
        assert np.allclose(cam["K"], v.camera.K) and np.allclose(cam["w2c"], v.camera.w2c)
        assert (cam["width"], cam["height"], entry["time"]) == (v.camera.width, v.camera.height, v.time)
    first = doc["train"][0]
    assert Path(first["image"]) == Path(scene.train[0].image_path).resolve()
    assert (inp / first["image_in_scene"]).resolve() == Path(first["image"]) and (inp / first["masks"]).is_file()
    assert "image" not in doc["test"][0]  # test views: cameras only
    assert np.array_equal(np.load(inp / "points.npy"), scene.points)
    assert (inp / "point_colors.npy").is_file() == (scene.point_colors is not None)  # nerfies: no colours


def test_prompts_give_each_objects_click_in_its_frame(written):
    scene, _, prompts, inp, info = written
    doc = json.loads((inp / "prompts.json").read_text())
    assert doc["rule"] == "gt-first-appearance" and len(doc["objects"]) == len(prompts.clicks) == info["n_clicks"] > 0
    names = frame_names(len(scene.test))
    for k, (obj, click) in enumerate(zip(doc["objects"], prompts.clicks), start=1):
        assert obj["object"] == k and (obj["u"], obj["v"]) == (click.u, click.v)
        assert obj["frame"] == names[click.view_index] and (obj["x"], obj["y"]) == (int(click.u), int(click.v))
        assert obj["positive"] is True  # the benchmark's clicks are positive
        assert read_mask(scene.gt_masks[click.view_index])[obj["y"], obj["x"]]  # on its object
    assert sum(len(c) for c in doc["frames"].values()) == len(doc["objects"])
    for frame, clicks in doc["frames"].items():
        img = cv2.imread(str(inp / "prompts" / f"{frame}.png"), cv2.IMREAD_UNCHANGED)
        assert img.dtype == np.uint8 and np.count_nonzero(img) == len(clicks)
        assert all(img[c["y"], c["x"]] == c["object"] for c in clicks)


# -- the output -------------------------------------------------------------------------------
def _write(out: Path, scene, value=255, size=None, frames=None, as_bool=False):
    out.mkdir(parents=True, exist_ok=True)
    for i, v in enumerate(scene.test):
        if frames is not None and i not in frames:
            continue
        h, w = size or (v.camera.height, v.camera.width)
        m = np.zeros((h, w), np.uint8)
        m[: h // 2] = 1 if as_bool else value
        cv2.imwrite(str(out / f"{i:05d}.png"), m)


def test_outputs_are_read_in_test_order(written, tmp_path):
    scene = written[0]
    _write(tmp_path / "a", scene)
    (tmp_path / "a" / "notes.txt").write_text("ignored")
    masks = read_outputs(tmp_path / "a", scene)
    assert len(masks) == len(scene.test) and all(m.dtype == bool and m[0].all() and not m[-1].any() for m in masks)
    _write(tmp_path / "b", scene, as_bool=True)  # 0/1 masks are masks too
    assert all(np.array_equal(a, b) for a, b in zip(masks, read_outputs(tmp_path / "b", scene)))


@pytest.mark.parametrize("case, message", [
    ("nothing", "no masks written (expected one PNG per test frame: 00000.png ... 00002.png)"),
    ("missing", "no mask for 1 of 3 test frames (00001.png)"),
    ("size", "00000.png in its output folder: 7x5 pixels, its test view is 64x48"),
    ("grey", "00000.png in its output folder: values reach only 3"),
    ("broken", "00000.png in its output folder: unreadable image"),
])
def test_bad_outputs_are_one_line_errors(written, tmp_path, case, message):
    scene = written[0]
    out = tmp_path / "out"
    out.mkdir()
    if case == "missing":
        _write(out, scene, frames={0, 2})
    elif case == "size":
        _write(out, scene, size=(5, 7))
    elif case == "grey":
        _write(out, scene, value=3)
    elif case == "broken":
        _write(out, scene)
        (out / "00000.png").write_bytes(b"not a png")
    with pytest.raises(CommandError) as err:
        read_outputs(out, scene, "its output folder")
    assert message in str(err.value) and "\n" not in str(err.value) and str(out) not in str(err.value)
    with pytest.raises(CommandError, match=f"^{out}"):  # without a label: the folder's path
        read_outputs(out, scene)
