import json
import math

import cv2
import numpy as np
import pytest

from benchmark.cli import main
from benchmark.scoring import (
    ScoringError,
    binarize,
    read_mask,
    score_directories,
    score_frame,
    score_masks,
)


def _write(path, arr):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), arr)


def test_frame_hand_computed():
    # 4x4 image; prediction covers the left half (8 px), ground truth the top half (8 px).
    pred = np.zeros((4, 4), bool)
    pred[:, :2] = True
    gt = np.zeros((4, 4), bool)
    gt[:2, :] = True
    fs = score_frame(pred, gt)
    assert (fs.intersection, fs.union, fs.total) == (4, 12, 16)
    assert fs.iou() == pytest.approx(4 / 12)
    # wrong pixels: pred-only 4 + gt-only 4 -> 8 correct of 16
    assert fs.acc == pytest.approx(8 / 16)


def test_empty_and_full_masks_under_both_metrics():
    empty = np.zeros((3, 5), bool)
    full = np.ones((3, 5), bool)
    both_empty = score_frame(empty, empty, "a")
    assert math.isnan(both_empty.iou("v1"))
    assert both_empty.iou("official") == 0.0
    assert both_empty.acc == 1.0
    assert score_frame(full, full).iou() == 1.0
    miss_all = score_frame(empty, full)
    assert miss_all.iou() == 0.0 and miss_all.acc == 0.0

    preds = {"a": empty, "b": full}
    gts = {"a": empty, "b": full}
    v1 = score_masks(preds, gts, "v1")
    off = score_masks(preds, gts, "official")
    assert v1.miou == 1.0  # frame a excluded
    assert off.miou == 0.5  # frame a counts as 0
    assert v1.macc == off.macc == 1.0
    assert v1.both_empty == ["a"]
    assert v1.pooled_iou == off.pooled_iou == 1.0


def test_pooled_iou_differs_from_mean():
    gt1 = np.zeros((10, 10), bool)
    gt1[:1, :1] = True  # 1 px object, missed
    gt2 = np.ones((10, 10), bool)  # 100 px object, hit
    r = score_masks({"0": np.zeros_like(gt1), "1": gt2}, {"0": gt1, "1": gt2})
    assert r.miou == pytest.approx(0.5)
    assert r.pooled_iou == pytest.approx(100 / 101)


def test_binarize_rules():
    u8 = np.array([[0, 127, 128, 255]], np.uint8)
    assert binarize(u8).tolist() == [[False, False, True, True]]
    f = np.array([[0.0, 0.49, 0.5, 1.0]])
    assert binarize(f).tolist() == [[False, False, True, True]]
    rgb = np.zeros((1, 2, 3), np.uint8)
    rgb[0, 0] = (255, 255, 0)  # mean 170 -> on
    rgb[0, 1] = (255, 0, 0)  # mean 85 -> off
    assert binarize(rgb).tolist() == [[True, False]]
    with pytest.raises(ScoringError, match="NaN"):
        binarize(np.array([[np.nan]]))
    with pytest.raises(ScoringError, match="shape"):
        binarize(np.zeros((2, 2, 2, 2)))


def test_binarize_reads_0_1_and_refuses_what_it_cannot_tell():
    # 0/1 is binary in any integer type (it used to threshold at 128 and read as empty)
    assert binarize(np.array([[0, 1, 1]], np.uint8)).tolist() == [[False, True, True]]
    assert binarize(np.array([[0, 1]], np.uint16)).tolist() == [[False, True]]
    # 0/255 is binary even in 16 bits, where half the range is 32768
    assert binarize(np.array([[0, 255]], np.uint16)).tolist() == [[False, True]]
    # grey levels reaching half the range: thresholded (anti-aliased edges)
    assert binarize(np.array([[0, 1, 127, 128, 255]], np.uint8)).tolist() == [[False, False, False, True, True]]
    assert not binarize(np.zeros((2, 2), np.uint8)).any()  # empty stays empty
    # neither 0/1 nor 0/255 and below half the range: an error, never an empty mask
    with pytest.raises(ScoringError, match=r"m.png: values reach only 3, below 128"):
        binarize(np.array([[0, 3]], np.uint8), name="m.png")
    red = np.zeros((1, 2, 3), np.uint8)
    red[0, 0] = (255, 0, 0)
    with pytest.raises(ScoringError, match="channel mean values reach only 85"):
        binarize(red)
    with pytest.raises(ScoringError, match="below 32768"):
        binarize(np.array([[0, 100, 255]], np.uint16))
    alpha_only = np.zeros((1, 2, 4), np.uint8)
    alpha_only[0, 0, 3] = 255
    with pytest.raises(ScoringError, match="only in the alpha channel"):
        binarize(alpha_only)
    with pytest.raises(ScoringError, match="negative"):
        binarize(np.array([[0, -1]], np.int16))
    with pytest.raises(ScoringError, match=r"expected \[0, 1\]"):
        binarize(np.array([[0.0, 2.0]]))
    assert binarize(np.array([[0.0, 255.0]])).tolist() == [[False, True]]


def test_png_0_1_ground_truth_under_v1(tmp_path):
    gt = np.zeros((4, 4), np.uint8)
    gt[:2] = 1
    _write(tmp_path / "gt" / "00000.png", gt)
    _write(tmp_path / "pred" / "00000.png", gt * 255)
    assert score_directories(tmp_path / "pred", tmp_path / "gt").miou == 1.0


def test_png_0_255_and_rgb_inputs(tmp_path):
    gt = np.zeros((6, 8), np.uint8)
    gt[2:5, 3:7] = 255
    _write(tmp_path / "gt" / "00000.png", gt)
    rgb = np.zeros((6, 8, 3), np.uint8)
    rgb[2:5, 3:6] = (200, 200, 200)
    _write(tmp_path / "pred" / "00000.png", rgb)
    assert read_mask(tmp_path / "gt" / "00000.png").sum() == 12
    r = score_directories(tmp_path / "pred", tmp_path / "gt")
    assert r.miou == pytest.approx(9 / 12)
    assert r.macc == pytest.approx(45 / 48)


def test_missing_prediction_is_empty_and_listed(tmp_path):
    gt = np.full((4, 4), 255, np.uint8)
    for i in range(2):
        _write(tmp_path / "gt" / f"{i:05d}.png", gt)
    _write(tmp_path / "pred" / "00000.png", gt)
    r = score_directories(tmp_path / "pred", tmp_path / "gt")
    assert r.missing == ["00001"]
    assert r.miou == pytest.approx(0.5)


def test_size_mismatch_names_file(tmp_path):
    _write(tmp_path / "gt" / "00000.png", np.zeros((4, 4), np.uint8))
    _write(tmp_path / "pred" / "00000.png", np.zeros((4, 5), np.uint8))
    with pytest.raises(ScoringError, match=r"pred/00000.png: size 5x4 differs"):
        score_directories(tmp_path / "pred", tmp_path / "gt")


def test_no_matching_frame_and_unreadable_file(tmp_path):
    _write(tmp_path / "gt" / "00000.png", np.zeros((4, 4), np.uint8))
    (tmp_path / "pred").mkdir()
    with pytest.raises(ScoringError, match="no prediction matches"):
        score_directories(tmp_path / "pred", tmp_path / "gt")
    _write(tmp_path / "pred" / "00007.png", np.zeros((4, 4), np.uint8))
    with pytest.raises(ScoringError, match="00007.png: no ground-truth frame"):
        score_directories(tmp_path / "pred", tmp_path / "gt")
    (tmp_path / "pred" / "00007.png").unlink()
    (tmp_path / "pred" / "00000.png").write_bytes(b"not a png")
    with pytest.raises(ScoringError, match="00000.png: unreadable image"):
        score_directories(tmp_path / "pred", tmp_path / "gt")


def test_per_object_scores(tmp_path):
    a = np.zeros((4, 4), np.uint8)
    a[:2] = 255
    b = np.zeros((4, 4), np.uint8)
    b[2:] = 255
    _write(tmp_path / "gt" / "00000.png", a | b)
    _write(tmp_path / "pred" / "00000.png", a)
    for name, m in (("cup", a), ("hand", b)):
        _write(tmp_path / "gt" / name / "00000.png", m)
    _write(tmp_path / "pred" / "cup" / "00000.png", a)
    _write(tmp_path / "pred" / "hand" / "00000.png", np.zeros_like(b))
    r = score_directories(tmp_path / "pred", tmp_path / "gt")
    assert r.miou == 0.5
    assert r.per_object["cup"].miou == 1.0
    assert r.per_object["hand"].miou == 0.0


def test_cli_json_and_error(tmp_path, capsys):
    gt = np.zeros((4, 4), np.uint8)
    gt[:2] = 255
    _write(tmp_path / "gt" / "00000.png", gt)
    _write(tmp_path / "gt" / "00001.png", np.zeros((4, 4), np.uint8))
    _write(tmp_path / "pred" / "00000.png", gt)
    _write(tmp_path / "pred" / "00001.png", np.zeros((4, 4), np.uint8))
    assert main(["score", str(tmp_path / "pred"), str(tmp_path / "gt"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {"miou", "macc", "pooled_iou", "n_frames", "metric", "per_frame"} <= out.keys()
    assert out["miou"] == 1.0 and out["n_frames"] == 2 and out["metric"] == "v1"
    assert out["per_frame"][1] == {
        "frame": "00001", "iou": None, "acc": 1.0, "intersection": 0, "union": 0, "missing": False
    }
    assert main(["score", str(tmp_path / "pred"), str(tmp_path / "gt"), "--metric", "official",
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["miou"] == 0.5
    assert main(["score", str(tmp_path / "nope"), str(tmp_path / "gt")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "nope: prediction directory not found" in err
    assert "\n" not in err


def test_help_lists_commands(capsys):
    assert main(["--help"]) == 0
    assert "score" in capsys.readouterr().out
