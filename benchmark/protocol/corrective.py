"""The robot user of interactive segmentation (RITM's, SimpleClick's, SAM's evaluation): after
the first clicks, each next click goes to the most interior pixel (the distance-transform
maximum) of the largest error region of the click frames: positive where the object was missed,
negative where something else was selected. A person who clicks in one view also watches the
selection play through the sequence; the robot does so in a few check frames (test frames spread
evenly over the sequence): a click that makes the click and check frames worse, or changes
nothing in them, is undone, as a person would undo it: it is spent, and its region is left alone
after (or, with an ``undone_radius``, the region's pixels near it, until ``region_tries`` clicks
in it were undone). It stops when every click frame reaches the target IoU, the budget of extra
clicks is spent, or no error is left to click. Only the click and check frames' ground truth is
read, as a person looks at the views they click in and watch.

The score after k clicks gives the curve; the number of clicks a sequence needs to reach an IoU
(NoC@85, NoC@90) counts the budget's clicks + 1 where it never does, as the standard does.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from benchmark.protocol.prompts import mask_regions
from trase.prompts import Click

# in the evaluate stage's key: another robot user, or another rule for what a click selects
# (trase.prompts.clicks_to_clusters, benchmark.methods.click_selection), makes other clicks.
# 2: a click that changes nothing is undone, not kept (the robot goes on elsewhere)
# 3: a click is judged on the check frames too (a click that helps its view and costs the rest of
# the sequence is undone)
PROTOCOL_VERSION = 3


def iou(pred: np.ndarray, gt: np.ndarray) -> float:
    """IoU of two bool masks [H, W]; 1 where both are empty."""
    union = np.logical_or(pred, gt).sum()
    return 1.0 if union == 0 else float(np.logical_and(pred, gt).sum() / union)


def _tries_in(region: np.ndarray, tried: list[Click]) -> int:
    """How many of the ``tried`` clicks (undone, of the region's frame and polarity) lie in ``region``."""
    return sum(bool(region[int(c.v), int(c.u)]) for c in tried)


def _away_from(error: np.ndarray, tried: list[Click], radius: float) -> np.ndarray:
    """``error`` [H, W] bool without its pixels (centres) within ``radius`` px of a ``tried`` click
    (undone, of this frame and polarity)."""
    if not tried:
        return error
    rows, cols = np.mgrid[: error.shape[0], : error.shape[1]] + 0.5  # [2, H, W] pixel centres
    out = error.copy()
    for c in tried:
        out &= (rows - c.v) ** 2 + (cols - c.u) ** 2 > radius**2
    return out


def _tried_out(error: np.ndarray, tried: list[Click], tries: int) -> np.ndarray:
    """``error`` [H, W] bool without its connected regions that hold ``tries`` or more of the
    ``tried`` clicks: a person who failed that often there moves on."""
    if len(tried) < tries:
        return error
    out = error.copy()
    for _, _, _, region in mask_regions(error, min_area=1):
        if _tries_in(region, tried) >= tries:
            out &= ~region
    return out


def next_click(preds: dict[int, np.ndarray], gts: dict[int, np.ndarray], frames: dict[int, tuple[str, float]],
               negatives: bool = True, undone: Sequence[Click] = (), undone_radius: float = 0.0,
               region_tries: int = 0) -> Click | None:
    """The click at the most interior pixel of the largest error region over the click frames
    (``frames``: view index -> (view name, time)); positive in a missed region (ground truth
    not predicted), negative in a wrongly predicted one (missed regions only where
    ``negatives`` is False: a method without negative clicks). A region where a click of its
    polarity was ``undone`` is left alone; with ``undone_radius`` > 0 only its pixels within that
    many px of the undone click are, and the rest of it can be clicked until ``region_tries``
    clicks in it were undone (0: no limit). Ties: missed before wrong, then the frames in order.
    None where no such error is left."""
    best = None  # (area, order, click)
    for order, i in enumerate(sorted(frames)):
        pred, gt = np.asarray(preds[i], dtype=bool), np.asarray(gts[i], dtype=bool)
        errors = ((True, gt & ~pred), (False, pred & ~gt)) if negatives else ((True, gt & ~pred),)
        for positive, error in errors:
            tried = [c for c in undone if c.view_index == i and c.positive == positive]
            if undone_radius > 0:
                if region_tries > 0:
                    error = _tried_out(error, tried, region_tries)
                error = _away_from(error, tried, undone_radius)
                regions = mask_regions(error, min_area=1) if error.any() else []
            else:
                regions = [r for r in mask_regions(error, min_area=1) if not _tries_in(r[3], tried)]
            if not regions:
                continue
            area, u, v, _ = regions[0]
            rank = (area, -(2 * order + (not positive)))
            if best is None or rank > best[0]:
                name, time = frames[i]
                best = (rank, Click(u, v, name, time, i, positive))
    return None if best is None else best[1]


def check_frames(n_views: int, click_frames: Sequence[int], count: int) -> list[int]:
    """``count`` test frames (of ``n_views``) spread evenly over the sequence, none of them a click
    frame: the frames the robot user watches besides those it clicks in. Fewer where the
    sequence has no more frames."""
    free = [i for i in range(n_views) if i not in set(click_frames)]
    if count <= 0 or not free:
        return []
    picks = np.linspace(0, len(free) - 1, count + 2)[1:-1] if count < len(free) else np.arange(len(free))
    return sorted({free[round(p)] for p in picks})


@dataclasses.dataclass
class RobotRun:
    """What the robot user did from its first clicks."""

    clicks: list[Click]  # the first clicks, then the corrective ones it kept
    spent: list[tuple[Click, bool]]  # every corrective click in order, and whether it was kept
    curve: list[float]  # the click and check frames' mean IoU after the first clicks and after each spent click


def corrective_clicks(first: list[Click], predict: Callable[[list[Click]], dict[int, np.ndarray]],
                      gts: dict[int, np.ndarray], budget: int, target: float, negatives: bool = True,
                      min_gain: float = 0.0, undone_radius: float = 0.0, region_tries: int = 0) -> RobotRun:
    """The first clicks, then corrective ones. ``predict``: clicks -> the predicted masks of the
    frames of ``gts`` (view index -> bool [H, W]); ``gts``: the ground truth of the click frames
    (those of ``first``) and of any check frames; ``budget``: the most corrective clicks;
    ``negatives``: whether the method takes negative clicks (else only missed regions get
    clicks). Clicks go to the click frames only. A click that does not raise the mean IoU over
    all of ``gts``' frames by more than ``min_gain``, or changes nothing in them, is undone, as a
    person undoes it, and spent: the score stays and its region is left alone (with
    ``undone_radius`` > 0: the region's pixels within that many px of it, until ``region_tries``
    clicks in the region were undone). Stops once every click frame reaches ``target``, the
    budget is spent or no error is left to click."""
    if not first:
        raise ValueError("the robot user starts from at least one click")
    frames = {c.view_index: (c.view, c.time) for c in first}
    missing = sorted(set(frames) - set(gts))
    if missing:
        raise ValueError(f"no ground truth for the click frames {missing}")
    watched = sorted(gts)

    def score(preds) -> dict[int, float]:
        return {i: iou(preds[i], gts[i]) for i in watched}

    run = RobotRun(list(first), [], [])
    preds = predict(run.clicks)
    ious = score(preds)
    run.curve.append(float(np.mean(list(ious.values()))))
    while min(ious[i] for i in frames) < target and len(run.spent) < budget:
        click = next_click(preds, gts, frames, negatives, [c for c, kept in run.spent if not kept], undone_radius,
                           region_tries)
        if click is None:
            break
        trial = predict([*run.clicks, click])
        trial_ious = score(trial)
        better = float(np.mean(list(trial_ious.values()))) - run.curve[-1]
        same = all(np.array_equal(trial[i], preds[i]) for i in watched)
        kept = better > min_gain or (better == min_gain == 0 and not same)  # worse, or no change: undone
        run.spent.append((click, kept))
        if kept:
            run.clicks.append(click)
            preds, ious = trial, trial_ious
        run.curve.append(float(np.mean(list(ious.values()))))
    return run


def clicks_to_reach(curve: Sequence[float], first: int, target: float, budget: int) -> int:
    """How many clicks a curve (the score after ``first``, ``first`` + 1, ... clicks) needs to
    reach ``target``; ``first`` + ``budget`` + 1 where it never does."""
    for k, score in enumerate(curve):
        if score >= target:
            return first + k
    return first + budget + 1


__all__ = ["PROTOCOL_VERSION", "RobotRun", "check_frames", "clicks_to_reach", "corrective_clicks", "iou", "next_click"]
