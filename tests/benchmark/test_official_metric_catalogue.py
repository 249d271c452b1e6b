"""A catalogue of mask files people actually write, scored by both metrics, with every expected
value worked out by hand on 4x4 images.

``official`` must give what the public evaluation script (metrics_segmentation.py of the
paper's code) gives: a prediction pixel is foreground when the mean of all its channels, alpha
included, is non-zero; the ground truth is read as stored: non-zero pixels are foreground for
IoU, and accuracy counts the pixels where the prediction (0/1) equals the stored value.
``v1`` binarises every mask by one rule (0/1 and 0/255 binary, grey levels at >= 128, anything
else an error).

Unless a case says otherwise the ground truth is an 8-bit grey PNG holding 255 in the top two
rows (8 pixels) and the prediction covers the left two columns (8 pixels):

    GT (top half)    prediction (left half)
    X X X X          X X . .
    X X X X          X X . .
    . . . .          X X . .
    . . . .          X X . .

Intersection 4 (top-left block), union 12, so IoU 4/12. Pixels right: 4 foreground (top-left)
+ 4 background (bottom-right) = 8 of 16. The public script's accuracy on a 0/255 ground truth
counts only the background ones, since a prediction of 1 never equals 255: 4 of 16.
"""

import json
import math

import numpy as np
import pytest
from PIL import Image

from benchmark.cli import main
from benchmark.scoring import ScoringError, metric_version, score_directories

X = 255
GT_255 = [[X, X, X, X], [X, X, X, X], [0, 0, 0, 0], [0, 0, 0, 0]]
LEFT = [[X, X, 0, 0], [X, X, 0, 0], [X, X, 0, 0], [X, X, 0, 0]]
EMPTY = [[0] * 4] * 4


def _rgb(grey):
    """A grey 4x4 written out as three equal channels."""
    g = np.array(grey, np.uint8)
    return np.stack([g, g, g], axis=2)


def _save(path, array, mode):
    path.parent.mkdir(parents=True, exist_ok=True)
    a = np.asarray(array)
    image = Image.fromarray(a) if a.dtype == bool else Image.fromarray(a, mode)  # bool: mode "1"
    assert image.mode == mode
    image.save(path)


def _pair(tmp_path, pred, gt, frame="00000.png"):
    """Write one frame: ``pred`` and ``gt`` are (array, PIL mode)."""
    _save(tmp_path / "pred" / frame, *pred)
    _save(tmp_path / "gt" / frame, *gt)
    return tmp_path / "pred", tmp_path / "gt"


# One frame each: (prediction, ground truth) as (array, mode);
# official (IoU, script accuracy, pixel accuracy); v1 (IoU, accuracy) or the start of its error.
RED = np.zeros((4, 4, 3), np.uint8)
RED[:, :2, 0] = 255  # pure red where the mask is: channel mean 85
RGBA_OPAQUE = np.zeros((4, 4, 4), np.uint8)
RGBA_OPAQUE[..., :3] = _rgb(LEFT)
RGBA_OPAQUE[..., 3] = 255  # opaque black background: every pixel's channel mean is non-zero
RGBA_ALPHA_ONLY = np.zeros((4, 4, 4), np.uint8)
RGBA_ALPHA_ONLY[..., 3] = LEFT  # the mask lives in alpha only
ANTI_ALIASED = [[X, 200, 100, 0], [X, 200, 100, 0], [128, 60, 10, 0], [0, 0, 0, 0]]
GT_01 = [[1, 1, 1, 1], [1, 1, 1, 1], [0, 0, 0, 0], [0, 0, 0, 0]]
GT_GREY = [[X, X, X, X], [100, 100, 100, 100], [0, 0, 0, 0], [0, 0, 0, 0]]
GT_LABELS = [[3, 3, 3, 3], [3, 3, 3, 3], [0, 0, 0, 0], [0, 0, 0, 0]]

CATALOGUE = {
    # 0/255 in three channels: the kind the public code writes
    "clean": ((_rgb(LEFT), "RGB"), (np.array(GT_255, np.uint8), "L"), (4 / 12, 4 / 16, 8 / 16), (4 / 12, 8 / 16)),
    # official: every non-zero value is foreground: columns 0-2 of rows 0-2 (9 px); intersection 6
    # (rows 0-1, columns 0-2), union 8 + 9 - 6 = 11; script accuracy: background right where
    # both are 0: rows 2-3 (8) less the 3 predicted in row 2 = 5; pixel accuracy 16 - (11 - 6) = 11.
    # v1: >= 128 keeps 255 and 200 in rows 0-1 and the 128 of row 2: 5 px; intersection 4,
    # union 8 + 5 - 4 = 9; wrong 9 - 4 = 5, right 11.
    "anti-aliased": ((_rgb(ANTI_ALIASED), "RGB"), (np.array(GT_255, np.uint8), "L"),
                     (6 / 11, 5 / 16, 11 / 16), (4 / 9, 11 / 16)),
    # official: channel mean 85 is non-zero, so the left half as in "clean"; v1 cannot tell
    "coloured": ((RED, "RGB"), (np.array(GT_255, np.uint8), "L"), (4 / 12, 4 / 16, 8 / 16), "channel mean values reach only 85"),
    # official: alpha 255 everywhere makes all 16 pixels foreground: intersection 8, union 16;
    # a prediction of 1 never equals 255: script accuracy 0; pixel accuracy 8 of 16.
    # v1 drops alpha: as "clean".
    "RGBA opaque": ((RGBA_OPAQUE, "RGBA"), (np.array(GT_255, np.uint8), "L"), (8 / 16, 0 / 16, 8 / 16), (4 / 12, 8 / 16)),
    # official: the alpha channel alone makes the mean non-zero (63.75) on the left half: as "clean"
    "RGBA alpha only": ((RGBA_ALPHA_ONLY, "RGBA"), (np.array(GT_255, np.uint8), "L"), (4 / 12, 4 / 16, 8 / 16),
                        "colour channels all zero and the mask only in the alpha channel"),
    # a 0/1 ground truth: 1 == True, so the script's accuracy is the pixel accuracy; v1 reads 0/1
    # as binary (it used to threshold at 128 and score IoU 0)
    "0/1 ground truth": ((_rgb(LEFT), "RGB"), (np.array(GT_01, np.uint8), "L"), (4 / 12, 8 / 16, 8 / 16), (4 / 12, 8 / 16)),
    # a 1-bit PNG is read as bool: the script's accuracy is the pixel accuracy
    "1-bit ground truth": ((_rgb(LEFT), "RGB"), (np.array(GT_01, bool), "1"), (4 / 12, 8 / 16, 8 / 16), (4 / 12, 8 / 16)),
    # grey one-channel prediction: the script cannot read it (it averages over the width); its
    # non-zero pixels are foreground, as for channel images; v1 reads 0/255
    "grey prediction": ((np.array(LEFT, np.uint8), "L"), (np.array(GT_255, np.uint8), "L"), (4 / 12, 4 / 16, 8 / 16), (4 / 12, 8 / 16)),
    # grey ground truth, 255 in row 0 and 100 in row 1: official foreground is both rows; neither
    # value equals 1: script accuracy 4 of 16. v1: >= 128 keeps row 0 only (4 px): intersection 2,
    # union 4 + 8 - 2 = 10, wrong 8, right 8.
    "grey ground truth": ((_rgb(LEFT), "RGB"), (np.array(GT_GREY, np.uint8), "L"), (4 / 12, 4 / 16, 8 / 16), (2 / 10, 8 / 16)),
    # a label map (values 0/3): official non-zero = foreground, 3 never equals 1; v1 cannot tell
    "label-map ground truth": ((_rgb(LEFT), "RGB"), (np.array(GT_LABELS, np.uint8), "L"), (4 / 12, 4 / 16, 8 / 16),
                               "values reach only 3"),
}


@pytest.mark.parametrize("kind", list(CATALOGUE))
def test_catalogue_official(tmp_path, kind):
    pred, gt, (iou, acc, pixel_acc), _ = CATALOGUE[kind]
    r = score_directories(*_pair(tmp_path, pred, gt), "official")
    (f,) = r.frames
    assert f.iou("official") == iou
    assert f.acc == acc
    assert f.pixel_acc == pixel_acc
    assert r.miou == iou and r.macc == acc and r.pixel_macc == pixel_acc
    differs = [n for n in r.notes if n.startswith("mAcc is the public script's")]
    assert bool(differs) == (acc != pixel_acc)


@pytest.mark.parametrize("kind", list(CATALOGUE))
def test_catalogue_v1(tmp_path, kind):
    pred, gt, _, expected = CATALOGUE[kind]
    pred_dir, gt_dir = _pair(tmp_path, pred, gt)
    if isinstance(expected, str):
        with pytest.raises(ScoringError, match=expected) as err:
            score_directories(pred_dir, gt_dir, "v1")
        assert "00000.png" in str(err.value) and "\n" not in str(err.value)
        return
    iou, acc = expected
    r = score_directories(pred_dir, gt_dir, "v1")
    (f,) = r.frames
    assert (f.iou("v1"), f.acc) == (iou, acc)


def _sequence(tmp_path, preds: dict, gts: dict):
    for name, arr in gts.items():
        _save(tmp_path / "gt" / name, np.array(arr, np.uint8), "L")
    for name, arr in preds.items():
        _save(tmp_path / "pred" / name, _rgb(arr), "RGB")
    return tmp_path / "pred", tmp_path / "gt"


def test_missing_prediction(tmp_path):
    # frame 00001 has no prediction: official skips it (mIoU over 00000 alone); v1 scores an empty
    # prediction: IoU 0 and 8 of 16 right (the bottom half), so mIoU (1/3 + 0) / 2
    dirs = _sequence(tmp_path, {"00000.png": LEFT}, {"00000.png": GT_255, "00001.png": GT_255})
    off = score_directories(*dirs, "official")
    assert off.n_frames == 1 and off.missing == ["00001"] and off.skipped == ["00001"]
    assert (off.miou, off.macc) == (4 / 12, 4 / 16)
    v1 = score_directories(*dirs, "v1")
    assert v1.n_frames == 2 and v1.missing == ["00001"]
    assert v1.miou == pytest.approx((4 / 12 + 0) / 2, rel=1e-15) and v1.macc == 8 / 16


def test_extra_prediction(tmp_path):
    # 00005.png has no ground truth: official ignores and lists it; v1 stops naming it
    dirs = _sequence(tmp_path, {"00000.png": LEFT, "00005.png": LEFT}, {"00000.png": GT_255})
    off = score_directories(*dirs, "official")
    assert off.extra == ["00005.png"] and off.n_frames == 1 and off.miou == 4 / 12
    with pytest.raises(ScoringError, match="00005.png: no ground-truth frame"):
        score_directories(*dirs, "v1")


def test_prediction_matched_by_file_name_under_official(tmp_path):
    # the script opens the ground truth's file name in the prediction folder: 00000.jpg is not
    # 00000.png, so the frame is missing and the file extra (v1 matches by stem)
    _save(tmp_path / "gt" / "00000.png", np.array(GT_255, np.uint8), "L")
    _save(tmp_path / "gt" / "00001.png", np.array(GT_255, np.uint8), "L")
    _save(tmp_path / "pred" / "00000.png", _rgb(LEFT), "RGB")
    _save(tmp_path / "pred" / "00001.bmp", _rgb(LEFT), "RGB")
    off = score_directories(tmp_path / "pred", tmp_path / "gt", "official")
    assert off.missing == ["00001"] and off.extra == ["00001.bmp"] and off.n_frames == 1
    assert score_directories(tmp_path / "pred", tmp_path / "gt", "v1").n_frames == 2


def test_both_empty_frame(tmp_path):
    # frame 00001: empty prediction and empty ground truth. official: IoU 0 (empty union), accuracy
    # 16/16; mIoU (1/3 + 0) / 2, mAcc (4/16 + 1) / 2, pixel mAcc (8/16 + 1) / 2.
    # v1: no IoU for 00001, so mIoU 1/3; mAcc (8/16 + 1) / 2.
    dirs = _sequence(tmp_path, {"00000.png": LEFT, "00001.png": EMPTY}, {"00000.png": GT_255, "00001.png": EMPTY})
    off = score_directories(*dirs, "official")
    assert [f.iou("official") for f in off.frames] == [4 / 12, 0.0]
    assert [f.acc for f in off.frames] == [4 / 16, 1.0]
    assert off.miou == pytest.approx(1 / 6, rel=1e-15)
    assert off.macc == pytest.approx(0.625, rel=1e-15) and off.pixel_macc == pytest.approx(0.75, rel=1e-15)
    v1 = score_directories(*dirs, "v1")
    assert v1.both_empty == ["00001"] and math.isnan(v1.frames[1].iou("v1"))
    assert v1.miou == 4 / 12 and v1.macc == pytest.approx(0.75, rel=1e-15)


def test_every_frame_empty_is_noted(tmp_path):
    # the script stops here (it cannot average integer zeros); official gives 0 and says so
    dirs = _sequence(tmp_path, {"00000.png": EMPTY}, {"00000.png": EMPTY})
    off = score_directories(*dirs, "official")
    assert off.miou == 0.0 and off.macc == 1.0
    assert any("stops on this input" in n for n in off.notes)


def test_ground_truth_with_channels_is_an_error_under_official(tmp_path):
    # the script compares an [H, W] prediction with an [H, W, 3] ground truth and fails; v1 reads it
    dirs = _pair(tmp_path, (_rgb(LEFT), "RGB"), (_rgb(GT_255), "RGB"))
    with pytest.raises(ScoringError, match=r"gt/00000.png: ground truth with 3 channels"):
        score_directories(*dirs, "official")
    assert score_directories(*dirs, "v1").miou == 4 / 12


def test_grey_prediction_is_noted(tmp_path):
    dirs = _pair(tmp_path, (np.array(LEFT, np.uint8), "L"), (np.array(GT_255, np.uint8), "L"))
    off = score_directories(*dirs, "official")
    assert off.one_channel == ["00000"]
    assert any("one-channel prediction" in n for n in off.notes)


def test_metric_versions():
    assert metric_version("v1") == "v1/bin2"
    assert metric_version("official") == "official/script1"


def test_score_command_lists_what_official_skipped(tmp_path, capsys):
    dirs = _sequence(tmp_path, {"00000.png": LEFT, "00007.png": LEFT},
                     {"00000.png": GT_255, "00001.png": GT_255})
    assert main(["score", *map(str, dirs), "--metric", "official"]) == 0
    out = capsys.readouterr().out
    assert "metric     official/script1" in out
    assert "frames     1 scored" in out
    assert "mIoU       0.3333" in out and "mAcc       0.2500" in out
    assert "pixel mAcc 0.5000" in out
    assert "missing predictions (1, skipped): 00001" in out
    assert "extra predictions (1, ignored): 00007.png" in out
    assert "note: mAcc is the public script's" in out
    assert main(["score", *map(str, dirs), "--metric", "official", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["missing"] == ["00001"] and d["extra"] == ["00007.png"] and d["n_frames"] == 1
    assert d["per_frame"][0]["acc"] == 4 / 16 and d["per_frame"][0]["pixel_acc"] == 8 / 16
