"""Scores of a prediction folder against a ground-truth folder, frame by frame, paired by file
name (the rules: benchmark.scoring)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmark.scoring.reading import (
    IMAGE_SUFFIXES,
    OFFICIAL_SUFFIXES,
    ScoringError,
    check_metric,
    read_mask,
    read_official_ground_truth,
    read_official_prediction,
)
from benchmark.scoring.scores import ScoreResult, score_frame, score_masks


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
    check_metric(metric)
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
