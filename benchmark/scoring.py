"""Segmentation scores for novel views: per-frame IoU and accuracy, mIoU/mAcc, pooled IoU.

Two metric versions exist because the public evaluation script has rules we do not want to
inherit silently, yet published numbers were made with it:

* ``official``: the public script's rules. IoU of a frame whose union is empty is 0; mIoU and
  mAcc are plain means over all frames.
* ``v1`` (ours, default): frames where prediction and ground truth are both empty have no
  defined IoU; they are excluded from mIoU (accuracy still counts them) and counted in
  ``both_empty``.

In both versions masks are binarised by one explicit rule (``BINARIZE_RULE``), a missing
prediction is scored as an empty prediction and listed in ``missing``, and the rule is part
of the recorded ``metric_version``.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from benchmark.errors import UserError

METRICS = ("v1", "official")
BINARIZE_RULE = "bin1"  # integer images: >= half the dtype range; float: >= 0.5; RGB: channel mean
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".npy")


class ScoringError(UserError):
    """Bad scoring input; the message is one line naming the file and the problem."""


def metric_version(metric: str) -> str:
    """The string recorded with every score, e.g. ``v1/bin1``."""
    _check_metric(metric)
    return f"{metric}/{BINARIZE_RULE}"


def _check_metric(metric: str) -> None:
    if metric not in METRICS:
        raise ScoringError(f"unknown metric {metric!r}; choose one of {', '.join(METRICS)}")


def binarize(mask: np.ndarray, name: str = "mask") -> np.ndarray:
    """Binarise a mask image to bool [H, W].

    bool: as is. Unsigned/signed integers: >= half of the dtype's maximum (128 for 8-bit, so a
    0/255 PNG and a 0/1 PNG both work only if written as 0/255: a 0/1 uint8 image is all
    False; use bool or float for 0/1 data). Float: >= 0.5. Colour [H, W, 3|4]: mean of the
    colour channels (alpha ignored), then the rule of its dtype.
    """
    a = np.asarray(mask)
    if a.ndim == 3:
        if a.shape[2] == 1:
            a = a[..., 0]
        elif a.shape[2] in (3, 4):
            dtype = a.dtype
            a = a[..., :3].astype(np.float64).mean(axis=2)
            if dtype == np.bool_:
                return a >= 0.5
            if np.issubdtype(dtype, np.integer):
                return a >= _integer_threshold(dtype)
            return a >= 0.5
        else:
            raise ScoringError(f"{name}: expected [H,W] or [H,W,3|4] mask, got shape {a.shape}")
    if a.ndim != 2:
        raise ScoringError(f"{name}: expected [H,W] or [H,W,3|4] mask, got shape {a.shape}")
    if a.dtype == np.bool_:
        return a
    if np.issubdtype(a.dtype, np.integer):
        return a >= _integer_threshold(a.dtype)
    if np.issubdtype(a.dtype, np.floating):
        if not np.isfinite(a).all():
            raise ScoringError(f"{name}: mask contains NaN or Inf")
        return a >= 0.5
    raise ScoringError(f"{name}: unsupported mask dtype {a.dtype}")


def _integer_threshold(dtype: np.dtype) -> int:
    info = np.iinfo(dtype)
    return (int(info.max) + 1) // 2


def read_mask(path: str | Path) -> np.ndarray:
    """Read a mask file (image or .npy) and binarise it -> bool [H, W]."""
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


@dataclasses.dataclass(frozen=True)
class FrameScore:
    frame: str
    intersection: int
    union: int
    correct: int
    total: int
    missing: bool = False  # no prediction was given; scored as empty

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


def score_frame(pred: np.ndarray, gt: np.ndarray, frame: str = "frame") -> FrameScore:
    """Score one binary prediction [H, W] against binary ground truth [H, W]."""
    if pred.shape != gt.shape:
        raise ScoringError(
            f"{frame}: prediction is {pred.shape[1]}x{pred.shape[0]} but ground truth is "
            f"{gt.shape[1]}x{gt.shape[0]} (WxH)"
        )
    pred = pred.astype(bool, copy=False)
    gt = gt.astype(bool, copy=False)
    inter = int(np.count_nonzero(pred & gt))
    union = int(np.count_nonzero(pred | gt))
    total = int(gt.size)
    correct = total - (union - inter)  # wrong pixels are exactly the symmetric difference
    return FrameScore(frame, inter, union, correct, total)


@dataclasses.dataclass
class ScoreResult:
    metric: str
    frames: list[FrameScore]
    per_object: dict[str, "ScoreResult"] = dataclasses.field(default_factory=dict)

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
        return [f.frame for f in self.frames if f.missing]

    def to_dict(self) -> dict:
        """JSON-ready summary; NaN becomes None so the output is strict JSON."""
        out = {
            "miou": _json_float(self.miou),
            "macc": _json_float(self.macc),
            "pooled_iou": _json_float(self.pooled_iou),
            "n_frames": self.n_frames,
            "metric": self.metric,
            "metric_version": metric_version(self.metric),
            "both_empty": self.both_empty,
            "missing": self.missing,
            "per_frame": [
                {
                    "frame": f.frame,
                    "iou": _json_float(f.iou(self.metric)),
                    "acc": _json_float(f.acc),
                    "intersection": f.intersection,
                    "union": f.union,
                    "missing": f.missing,
                }
                for f in self.frames
            ],
        }
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
    """Score binary masks matched by frame name; a prediction absent or None is empty."""
    _check_metric(metric)
    extra = sorted(set(preds) - set(gts))
    if extra:
        raise ScoringError(f"prediction frame {extra[0]!r} has no ground truth")
    frames = []
    for name in sorted(gts):
        gt = gts[name]
        pred = preds.get(name)
        if pred is None:
            fs = score_frame(np.zeros_like(gt, dtype=bool), gt, name)
            fs = dataclasses.replace(fs, missing=True)
        else:
            fs = score_frame(pred, gt, name)
        frames.append(fs)
    return ScoreResult(metric, frames)


def _mask_files(directory: Path) -> dict[str, Path]:
    """Frame stem -> file, for every mask file directly inside ``directory``."""
    files: dict[str, Path] = {}
    for p in sorted(directory.iterdir()):
        if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES:
            if p.stem in files:
                raise ScoringError(f"{p}: two files for frame {p.stem!r} ({files[p.stem].name})")
            files[p.stem] = p
    return files


def score_directories(
    pred_dir: str | Path, gt_dir: str | Path, metric: str = "v1", per_object: bool = True
) -> ScoreResult:
    """Score every ground-truth frame in ``gt_dir`` against the same-named file in ``pred_dir``.

    Frames are matched by file stem (``00000.png`` <-> ``00000.png`` or ``00000.npy``).
    Subdirectories present in both are per-object masks (``<dir>/<object>/<frame>.png``)
    and are scored into ``per_object``.
    """
    _check_metric(metric)
    pred_dir, gt_dir = Path(pred_dir), Path(gt_dir)
    for d, what in ((pred_dir, "prediction"), (gt_dir, "ground-truth")):
        if not d.is_dir():
            raise ScoringError(f"{d}: {what} directory not found")
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
        pred = read_mask(p)
        if pred.shape != gts[k].shape:
            raise ScoringError(
                f"{p}: size {pred.shape[1]}x{pred.shape[0]} differs from ground truth "
                f"{gt_files[k]} {gts[k].shape[1]}x{gts[k].shape[0]}"
            )
        preds[k] = pred
    result = score_masks(preds, gts, metric)
    if per_object:
        for obj in _common_subdirs(pred_dir, gt_dir):
            result.per_object[obj] = score_directories(
                pred_dir / obj, gt_dir / obj, metric, per_object=False
            )
    return result


def _common_subdirs(a: Path, b: Path) -> list[str]:
    sa = {p.name for p in a.iterdir() if p.is_dir()}
    sb = {p.name for p in b.iterdir() if p.is_dir()}
    return sorted(sa & sb)


def mean_over(results: Iterable[ScoreResult], key: str) -> float:
    """Plain mean of a per-sequence metric (``miou``/``macc``) over sequences."""
    vals = [getattr(r, key) for r in results]
    vals = [v for v in vals if not math.isnan(v)]
    return float(np.mean(vals)) if vals else math.nan
