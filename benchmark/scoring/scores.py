"""Per-frame counts (intersection, union, correct pixels) and the scores over frames: mIoU,
mAcc, pooled IoU, under either metric version (the rules: benchmark.scoring)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping

import numpy as np

from benchmark.scoring.reading import (
    ScoringError,
    binarize,
    check_metric,
    metric_version,
    official_prediction,
)


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
    check_metric(metric)
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


def mean_over(results: Iterable[ScoreResult], key: str) -> float:
    """Plain mean of a per-sequence metric (``miou``/``macc``) over sequences."""
    vals = [getattr(r, key) for r in results]
    vals = [v for v in vals if not math.isnan(v)]
    return float(np.mean(vals)) if vals else math.nan
