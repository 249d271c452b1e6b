"""Segmentation scores for novel views: per-frame IoU and accuracy, mIoU/mAcc, pooled IoU.

Two metric versions. Published numbers were made with the public evaluation script of the
paper's code (``metrics_segmentation.py``), whose rules we reproduce but do not want to
inherit silently:

* ``official`` (label ``official/script1``): that script, rule for rule, so its numbers are the
  published kind.

  - Pairing: every image file in the ground-truth folder is a frame; its prediction is the file
    of the *same name* in the prediction folder (``00000.png`` <-> ``00000.png``). A frame with
    no prediction file is skipped (not scored) and listed in ``missing``; a prediction with no
    ground truth is ignored and listed in ``extra``.
  - Prediction: read as stored (PIL); a pixel is foreground when the mean of *all* its channels,
    alpha included, is non-zero: any grey fringe of an anti-aliased mask, any colour, and any
    opaque pixel of an RGBA file count. A one-channel file is outside the script (it averages
    the last axis, the image's width, and fails); here its non-zero pixels are foreground and
    the result says so (``notes``).
  - Ground truth: read as stored, never binarised. IoU counts its non-zero pixels as foreground;
    accuracy counts the pixels where the prediction (0 or 1) *equals the stored value*, so the
    foreground of a 0/255 file is never correct. That accuracy is the metric's; the pixel
    accuracy (ground truth read as non-zero = foreground) is given beside it (``pixel_acc``,
    ``pixel_macc``) and a note says when the two differ. A ground truth with channels is an
    error (the script fails on it).
  - IoU of a frame whose union is empty is 0; mIoU and mAcc are plain means over the scored
    frames (when every scored frame has an empty union the script itself stops; 0 is given and
    a note says so).

* ``v1`` (label ``v1/bin2``, ours, the default): every mask is binarised by one rule
  (``binarize``: 0/1 and 0/255 masks are binary, grey levels are thresholded at half the
  range, and a mask that cannot be read as binary is an error naming the file); a frame with
  no prediction is scored as an empty prediction and listed in ``missing``; a prediction with
  no ground truth is an error; frames where prediction and ground truth are both empty have no
  IoU and are left out of mIoU (accuracy still counts them) and listed in ``both_empty``.

The label (``metric_version``) is recorded with every score and changes whenever a metric's
rules change, so results of different rules are never mixed unnoticed. ``bin1`` (before): both
metrics binarised every mask at half the range (a 0/1 mask read as empty) and scored missing
predictions as empty.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from benchmark.errors import UserError

METRICS = ("v1", "official")
BINARIZE_RULE = "bin2"  # v1's rule, see ``binarize``
OFFICIAL_RULE = "script1"  # metrics_segmentation.py of yunjinli/TRASE (unchanged up to 9b25f77)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".npy")
OFFICIAL_SUFFIXES = tuple(s for s in IMAGE_SUFFIXES if s != ".npy")  # the script reads images only


class ScoringError(UserError):
    """Bad scoring input; the message is one line naming the file and the problem."""


def metric_version(metric: str) -> str:
    """The string recorded with every score: ``v1/bin2`` or ``official/script1``."""
    _check_metric(metric)
    return f"{metric}/{BINARIZE_RULE if metric == 'v1' else OFFICIAL_RULE}"


def _check_metric(metric: str) -> None:
    if metric not in METRICS:
        raise ScoringError(f"unknown metric {metric!r}; choose one of {', '.join(METRICS)}")


# --- v1: one binarisation rule ----------------------------------------------------------------


def binarize(mask: np.ndarray, name: str = "mask") -> np.ndarray:
    """Binarise a mask image to bool [H, W] by v1's rule (``bin2``).

    * Colour [H, W, 3|4]: the mean of the colour channels (alpha ignored) is the value; an RGBA
      image whose colour is all zero while its alpha varies is an error (the mask is in alpha).
      [H, W, 1] is one channel.
    * bool: as is (colour: mean >= 0.5).
    * Integers: a mask whose values are all 0 or 1 is binary (1 = foreground); all 0 or 255 is
      binary (255 = foreground); otherwise grey levels are thresholded at half the dtype's range
      (>= 128 for 8 bits), which needs the mask to reach that value: a mask whose values are
      neither 0/1 nor 0/255 and stay below half the range (a label map, a faint or a pure-red
      mask) cannot be read as binary and is an error, never an empty mask.
    * Floats: finite values in [0, 1] are thresholded at 0.5; 0/255 is binary; other values are
      an error.
    """
    a = np.asarray(mask)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim == 3 and a.shape[2] in (3, 4):
        colour = a[..., :3]
        if a.shape[2] == 4 and not colour.any() and a[..., 3].min() != a[..., 3].max():
            raise ScoringError(f"{name}: colour channels all zero and the mask only in the alpha "
                               "channel, which v1 ignores: store the mask in the colour channels")
        mean = colour.astype(np.float64).mean(axis=2)
        if a.dtype == np.bool_:
            return mean >= 0.5
        return _threshold(mean, a.dtype, name, "channel mean ")
    if a.ndim != 2:
        raise ScoringError(f"{name}: expected [H,W] or [H,W,3|4] mask, got shape {a.shape}")
    if a.dtype == np.bool_:
        return a
    if not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise ScoringError(f"{name}: unsupported mask dtype {a.dtype}")
    return _threshold(a, a.dtype, name, "")


def _threshold(values: np.ndarray, dtype: np.dtype, name: str, what: str) -> np.ndarray:
    """v1's rule on values of an image of ``dtype`` (``what``: how they were made, for errors)."""
    if np.issubdtype(dtype, np.floating) and not np.isfinite(values).all():
        raise ScoringError(f"{name}: mask contains NaN or Inf")
    if values.size == 0:
        return np.zeros(values.shape, bool)
    lo, hi = float(values.min()), float(values.max())
    if lo < 0:
        raise ScoringError(f"{name}: negative {what}value {lo:g} in a mask")
    if np.isin(values, (0, 1)).all():
        return values == 1
    if np.isin(values, (0, 255)).all():
        return values == 255
    if np.issubdtype(dtype, np.floating):
        if hi > 1:
            raise ScoringError(f"{name}: float mask {what}values up to {hi:g}: expected [0, 1] "
                               "(or exactly 0/255)")
        return values >= 0.5
    half = (int(np.iinfo(dtype).max) + 1) // 2
    if hi < half:
        raise ScoringError(
            f"{name}: {what}values reach only {hi:g}, below {half} (half the {np.dtype(dtype).name} "
            "range), and are neither 0/1 nor 0/255: cannot tell the foreground; save the mask as "
            "0/1 or 0/255")
    return values >= half


def read_mask(path: str | Path) -> np.ndarray:
    """Read a mask file (image or .npy) and binarise it by v1's rule -> bool [H, W]."""
    path = Path(path)
    if not path.is_file():
        raise ScoringError(f"{path}: file not found")
    if path.suffix.lower() == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except Exception as exc:  # numpy raises several types for corrupt files
            raise ScoringError(f"{path}: unreadable .npy ({exc.__class__.__name__})") from None
    else:
        import cv2

        arr = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if arr is None:
            raise ScoringError(f"{path}: unreadable image")
        if arr.ndim == 3 and arr.shape[2] >= 3:  # BGR(A) -> RGB(A); the mean is unchanged
            arr = arr[..., [2, 1, 0] + list(range(3, arr.shape[2]))]
    return binarize(arr, name=str(path))


# --- official: the public script's reading ----------------------------------------------------


def _read_stored(path: Path) -> tuple[np.ndarray, str]:
    """The image's samples as PIL stores them (what the public script sees) and its mode."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return np.asarray(im), im.mode
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise ScoringError(f"{path}: unreadable image ({exc.__class__.__name__})") from None


def official_prediction(stored: np.ndarray) -> np.ndarray:
    """The public script's prediction rule on stored samples -> bool [H, W]: foreground where
    the mean over all channels (alpha included) is non-zero; one channel: where it is non-zero
    (outside the script, which averages the last axis of any array)."""
    a = np.asarray(stored)
    if a.ndim == 3:
        return a.astype(np.float64).mean(axis=-1) != 0
    if a.ndim == 2:
        return a != 0
    raise ScoringError(f"prediction: expected [H,W] or [H,W,C], got shape {a.shape}")


def read_official_prediction(path: str | Path) -> tuple[np.ndarray, bool]:
    """(foreground bool [H, W], whether the file has one channel) by the public script's rule."""
    stored, _ = _read_stored(Path(path))
    return official_prediction(stored), stored.ndim == 2


def read_official_ground_truth(path: str | Path) -> np.ndarray:
    """The stored values [H, W], not binarised (the public script's ground truth)."""
    path = Path(path)
    stored, mode = _read_stored(path)
    if stored.ndim != 2:
        raise ScoringError(
            f"{path}: ground truth with {stored.shape[-1]} channels (mode {mode}); the public script "
            "compares it with a one-channel prediction and fails: save it as one channel, or use --metric v1")
    return stored


# --- counts and means -------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class FrameScore:
    frame: str
    intersection: int
    union: int
    correct: int  # pixels the metric counts as correct (official: prediction == stored ground truth)
    total: int
    missing: bool = False  # v1: no prediction was given; scored as empty
    pixel_correct: int | None = None  # pixels where prediction == ground truth read as non-zero

    @property
    def both_empty(self) -> bool:
        return self.union == 0

    def iou(self, metric: str = "v1") -> float:
        """IoU; NaN (undefined) for an empty union under v1, 0 under official."""
        if self.union == 0:
            return 0.0 if metric == "official" else math.nan
        return self.intersection / self.union

    @property
    def acc(self) -> float:
        return self.correct / self.total if self.total else math.nan

    @property
    def pixel_acc(self) -> float:
        """True pixel accuracy; equals ``acc`` unless the ground truth holds values other than 0/1."""
        n = self.correct if self.pixel_correct is None else self.pixel_correct
        return n / self.total if self.total else math.nan


def score_frame(pred: np.ndarray, gt: np.ndarray, frame: str = "frame") -> FrameScore:
    """Score a binary prediction [H, W] against a ground truth [H, W].

    IoU reads the ground truth's non-zero pixels as foreground. Accuracy counts the pixels
    where the prediction (0/1) equals the ground truth's value: for a bool (binarised) ground
    truth that is the pixel accuracy; for stored values (official) it is the public script's.
    """
    pred, gt = np.asarray(pred), np.asarray(gt)
    if pred.shape != gt.shape:
        raise ScoringError(
            f"{frame}: prediction is {pred.shape[1]}x{pred.shape[0]} but ground truth is "
            f"{gt.shape[1]}x{gt.shape[0]} (WxH)"
        )
    pred = pred.astype(bool, copy=False)
    fg = gt if gt.dtype == np.bool_ else gt != 0
    inter = int(np.count_nonzero(pred & fg))
    union = int(np.count_nonzero(pred | fg))
    total = int(gt.size)
    pixel_correct = total - (union - inter)  # wrong pixels are exactly the symmetric difference
    correct = pixel_correct if gt.dtype == np.bool_ else int(np.count_nonzero(pred == gt))
    return FrameScore(frame, inter, union, correct, total, pixel_correct=pixel_correct)


@dataclasses.dataclass
class ScoreResult:
    metric: str
    frames: list[FrameScore]
    per_object: dict[str, ScoreResult] = dataclasses.field(default_factory=dict)
    # official only: ground-truth frames with no prediction (not scored); predictions (file
    # names) with no ground truth (ignored); one-channel predictions (the script cannot read them)
    skipped: list[str] = dataclasses.field(default_factory=list)
    extra: list[str] = dataclasses.field(default_factory=list)
    one_channel: list[str] = dataclasses.field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    @property
    def miou(self) -> float:
        vals = [f.iou(self.metric) for f in self.frames]
        vals = [v for v in vals if not math.isnan(v)]
        return float(np.mean(vals)) if vals else math.nan

    @property
    def macc(self) -> float:
        return float(np.mean([f.acc for f in self.frames])) if self.frames else math.nan

    @property
    def pixel_macc(self) -> float:
        return float(np.mean([f.pixel_acc for f in self.frames])) if self.frames else math.nan

    @property
    def pooled_iou(self) -> float:
        inter = sum(f.intersection for f in self.frames)
        union = sum(f.union for f in self.frames)
        if union == 0:
            return 0.0 if self.metric == "official" else math.nan
        return inter / union

    @property
    def both_empty(self) -> list[str]:
        return [f.frame for f in self.frames if f.both_empty]

    @property
    def missing(self) -> list[str]:
        """Ground-truth frames without a prediction: scored as empty (v1) or skipped (official)."""
        return sorted([f.frame for f in self.frames if f.missing] + self.skipped)

    @property
    def notes(self) -> list[str]:
        """Where the official metric's figures need a word (empty under v1)."""
        if self.metric != "official":
            return []
        out = []
        differ = [f.frame for f in self.frames if f.pixel_acc != f.acc]
        if differ:
            out.append(
                f"mAcc is the public script's: it compares the prediction (0/1) with the stored ground-truth "
                f"values, which are not 0/1 in {len(differ)} of {self.n_frames} frames; the pixel accuracy "
                f"(ground truth non-zero = foreground) gives mAcc {self.pixel_macc:.4f}")
        if self.frames and all(f.union == 0 for f in self.frames):
            out.append("every scored frame has an empty union: the public script stops on this input "
                       "(it cannot average its integer IoUs of 0); 0 is given")
        if self.one_channel:
            out.append(
                f"{len(self.one_channel)} one-channel prediction(s) (e.g. {self.one_channel[0]}): the public "
                "script cannot read them (it averages over the image width); read here as non-zero = "
                "foreground, its rule for images with channels")
        return out

    def to_dict(self) -> dict:
        """JSON-ready summary; NaN becomes None so the output is strict JSON."""
        official = self.metric == "official"
        out = {
            "miou": _json_float(self.miou),
            "macc": _json_float(self.macc),
            "pooled_iou": _json_float(self.pooled_iou),
            "n_frames": self.n_frames,
            "metric": self.metric,
            "metric_version": metric_version(self.metric),
            "both_empty": self.both_empty,
            "missing": self.missing,
        }
        if official:
            out |= {"pixel_macc": _json_float(self.pixel_macc), "extra": list(self.extra), "notes": self.notes}
        out["per_frame"] = [
            {
                "frame": f.frame,
                "iou": _json_float(f.iou(self.metric)),
                "acc": _json_float(f.acc),
                **({"pixel_acc": _json_float(f.pixel_acc)} if official else {}),
                "intersection": f.intersection,
                "union": f.union,
                "missing": f.missing,
            }
            for f in self.frames
        ]
        if self.per_object:
            out["per_object"] = {
                name: {k: v for k, v in r.to_dict().items() if k != "per_frame"}
                for name, r in sorted(self.per_object.items())
            }
        return out


def _json_float(x: float) -> float | None:
    return None if x is None or math.isnan(x) else float(x)


def score_masks(
    preds: Mapping[str, np.ndarray | None],
    gts: Mapping[str, np.ndarray],
    metric: str = "v1",
) -> ScoreResult:
    """Score masks matched by frame name.

    v1: both sides are binarised by ``binarize`` (bool arrays pass as they are); a prediction
    absent or None is scored as empty; a prediction with no ground truth is an error.
    official: a prediction is read by ``official_prediction`` (bool arrays as they are), the
    ground truth is used as given (its stored values); a prediction absent or None is skipped
    and listed in ``missing``, one with no ground truth is ignored and listed in ``extra``.
    """
    _check_metric(metric)
    extra = sorted(set(preds) - set(gts))
    if extra and metric == "v1":
        raise ScoringError(f"prediction frame {extra[0]!r} has no ground truth")
    result = ScoreResult(metric, [], extra=extra if metric == "official" else [])
    for name in sorted(gts):
        pred = preds.get(name)
        if metric == "official":
            gt = np.asarray(gts[name])
            if gt.ndim != 2:
                raise ScoringError(f"{name}: ground truth must be one channel [H,W], got shape {gt.shape}")
            if pred is None:
                result.skipped.append(name)
                continue
            result.frames.append(score_frame(official_prediction(pred), gt, name))
            continue
        gt = binarize(gts[name], name=f"ground truth {name}")
        if pred is None:
            fs = dataclasses.replace(score_frame(np.zeros_like(gt), gt, name), missing=True)
        else:
            fs = score_frame(binarize(pred, name=f"prediction {name}"), gt, name)
        result.frames.append(fs)
    return result


# --- folders ----------------------------------------------------------------------------------


def _mask_files(directory: Path, suffixes: tuple[str, ...] = IMAGE_SUFFIXES) -> dict[str, Path]:
    """Frame stem -> file, for every mask file directly inside ``directory``."""
    files: dict[str, Path] = {}
    for p in sorted(directory.iterdir()):
        if p.is_file() and p.suffix.lower() in suffixes:
            if p.stem in files:
                raise ScoringError(f"{p}: two files for frame {p.stem!r} ({files[p.stem].name})")
            files[p.stem] = p
    return files


def score_directories(
    pred_dir: str | Path, gt_dir: str | Path, metric: str = "v1", per_object: bool = True
) -> ScoreResult:
    """Score every ground-truth frame in ``gt_dir`` against its file in ``pred_dir``.

    v1 matches frames by file stem (``00000.png`` <-> ``00000.png`` or ``00000.npy``); official
    by file name, as the public script does (``00000.png`` <-> ``00000.png`` only).
    Subdirectories present in both are per-object masks (``<dir>/<object>/<frame>.png``)
    and are scored into ``per_object``.
    """
    _check_metric(metric)
    pred_dir, gt_dir = Path(pred_dir), Path(gt_dir)
    for d, what in ((pred_dir, "prediction"), (gt_dir, "ground-truth")):
        if not d.is_dir():
            raise ScoringError(f"{d}: {what} directory not found")
    scorer = _score_official_directories if metric == "official" else _score_v1_directories
    result = scorer(pred_dir, gt_dir)
    if per_object:
        for obj in _common_subdirs(pred_dir, gt_dir):
            result.per_object[obj] = score_directories(
                pred_dir / obj, gt_dir / obj, metric, per_object=False
            )
    return result


def _score_v1_directories(pred_dir: Path, gt_dir: Path) -> ScoreResult:
    gt_files = _mask_files(gt_dir)
    if not gt_files:
        raise ScoringError(f"{gt_dir}: no ground-truth mask files")
    pred_files = _mask_files(pred_dir)
    extra = sorted(set(pred_files) - set(gt_files))
    if extra:
        raise ScoringError(f"{pred_files[extra[0]]}: no ground-truth frame named {extra[0]!r}")
    if not set(pred_files) & set(gt_files):
        raise ScoringError(f"{pred_dir}: no prediction matches a ground-truth frame name")
    gts = {k: read_mask(p) for k, p in gt_files.items()}
    preds = {}
    for k, p in pred_files.items():
        preds[k] = read_mask(p)
        _check_size(p, preds[k], gt_files[k], gts[k])
    return score_masks(preds, gts, "v1")


def _score_official_directories(pred_dir: Path, gt_dir: Path) -> ScoreResult:
    gt_files = _mask_files(gt_dir, OFFICIAL_SUFFIXES)
    if not gt_files:
        raise ScoringError(f"{gt_dir}: no ground-truth image files (the official metric reads images, not .npy)")
    pred_names = {p.name: p for p in pred_dir.iterdir() if p.is_file() and p.suffix.lower() in OFFICIAL_SUFFIXES}
    gt_names = {p.name for p in gt_files.values()}
    result = ScoreResult("official", [], extra=sorted(set(pred_names) - gt_names))
    for frame, g in gt_files.items():
        p = pred_names.get(g.name)
        if p is None:
            result.skipped.append(frame)
            continue
        gt = read_official_ground_truth(g)
        pred, one_channel = read_official_prediction(p)
        _check_size(p, pred, g, gt)
        if one_channel:
            result.one_channel.append(frame)
        result.frames.append(score_frame(pred, gt, frame))
    if not result.frames:
        raise ScoringError(f"{pred_dir}: no prediction has the file name of a ground-truth frame")
    return result


def _check_size(pred_path: Path, pred: np.ndarray, gt_path: Path, gt: np.ndarray) -> None:
    if pred.shape != gt.shape:
        raise ScoringError(
            f"{pred_path}: size {pred.shape[1]}x{pred.shape[0]} differs from ground truth "
            f"{gt_path} {gt.shape[1]}x{gt.shape[0]}"
        )


def _common_subdirs(a: Path, b: Path) -> list[str]:
    sa = {p.name for p in a.iterdir() if p.is_dir()}
    sb = {p.name for p in b.iterdir() if p.is_dir()}
    return sorted(sa & sb)


def mean_over(results: Iterable[ScoreResult], key: str) -> float:
    """Plain mean of a per-sequence metric (``miou``/``macc``) over sequences."""
    vals = [getattr(r, key) for r in results]
    vals = [v for v in vals if not math.isnan(v)]
    return float(np.mean(vals)) if vals else math.nan
