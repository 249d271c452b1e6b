"""Where a method's predicted masks are in a predictions folder, per sequence.

A predictions folder holds one folder per sequence, named after the sequence (the benchmark's
name, a publisher's folder alias, or a synthetic name such as ``synthetic``), in one of two
layouts:

* ``trase``: the output of the paper's public code (yunjinli/TRASE). ``render.py -m
  output/<DATASET>/<NAME> --segment_ids ...`` writes the test views' masks to
  ``<model>/test/ours_<iteration>/pred_masks/<idx:05d>.png`` (idx: the position in the test
  cameras, RGB 0/255), and ``metrics_segmentation.py -m <model> --benchmark_path
  <Dataset>-Mask/<scene>`` scores every ``test/<dir>/pred_masks`` against ``gt_masks/`` there.
  So the folder to give is ``output/<DATASET>``:
  ``<sequence>/test/<iteration dir>/pred_masks/<frame>.png``. With several iteration dirs
  holding ``pred_masks``, the highest ``ours_<N>`` is read and the others are listed.
* ``flat``: ``<sequence>/<frame>.png`` (any mask file ``trase-bench score`` reads).

``auto`` decides per sequence folder: a ``test/`` folder is the trase layout, mask files
directly inside are the flat one.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

from benchmark.errors import UserError
from benchmark.scoring import IMAGE_SUFFIXES

LAYOUTS = ("auto", "trase", "flat")
TRASE_PATTERN = "<sequence>/test/ours_<iteration>/pred_masks/<frame>.png"
FLAT_PATTERN = "<sequence>/<frame>.png"
_ITERATION = re.compile(r"^ours_(\d+)$")


class PredictionsError(UserError):
    """A predictions folder that cannot be read; one line naming the folder."""


@dataclasses.dataclass(frozen=True)
class SequencePredictions:
    folder: Path  # <predictions>/<sequence folder>
    masks_dir: Path  # the folder holding the mask files
    layout: str  # trase | flat
    iteration_dir: str | None = None  # trase: the iteration dir read (e.g. ours_30000)
    other_iteration_dirs: tuple[str, ...] = ()  # trase: iteration dirs with pred_masks not read

    def mask_files(self) -> list[Path]:
        """The mask files (``benchmark.scoring.IMAGE_SUFFIXES``), sorted by name."""
        return sorted(p for p in self.masks_dir.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)

    def other_entries(self) -> list[str]:
        """Names in the masks folder that are not mask files (ignored)."""
        masks = {p.name for p in self.mask_files()}
        return sorted(p.name for p in self.masks_dir.iterdir() if p.name not in masks)


def sequence_folders(root: Path) -> list[Path]:
    """The sequence folders of a predictions folder (not hidden), sorted; a clear error for a
    missing or empty folder, or for one sequence's model folder given in place of its parent."""
    root = Path(root)
    if not root.is_dir():
        raise PredictionsError(f"{root}: predictions folder not found")
    if (root / "test").is_dir() or _mask_files(root):
        what = "a model folder of the public code (test/)" if (root / "test").is_dir() else "mask files"
        raise PredictionsError(f"{root}: holds {what} directly; give the folder above it, with one folder per "
                               f"sequence named after the sequence ({TRASE_PATTERN} or {FLAT_PATTERN})")
    found = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not found:
        raise PredictionsError(f"{root}: no sequence folders (expected {TRASE_PATTERN} or {FLAT_PATTERN})")
    return found


def read_sequence(folder: Path, layout: str = "auto") -> SequencePredictions:
    """Where one sequence folder's masks are, in ``layout`` (auto: decided here)."""
    if layout not in LAYOUTS:
        raise PredictionsError(f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}")
    folder = Path(folder)
    has_test, n_files = (folder / "test").is_dir(), len(_mask_files(folder))
    if layout == "auto":
        if not has_test and not n_files:
            raise PredictionsError(f"{folder}: no predictions: neither test/<iteration dir>/pred_masks/ (layout "
                                   "trase) nor mask files (layout flat)")
        layout = "trase" if has_test else "flat"
    if layout == "flat":
        if not n_files:
            hint = "; it holds test/: use --layout trase (or auto)" if has_test else ""
            raise PredictionsError(f"{folder}: no mask files (layout flat: {FLAT_PATTERN}){hint}")
        return SequencePredictions(folder, folder, "flat")
    if not has_test:
        hint = f"; it holds {n_files} mask file(s) directly: use --layout flat (or auto)" if n_files else ""
        raise PredictionsError(f"{folder}: no test/ folder (layout trase: {TRASE_PATTERN}){hint}")
    return _trase(folder)


def _trase(folder: Path) -> SequencePredictions:
    test = folder / "test"
    candidates = sorted(d.name for d in test.iterdir() if (d / "pred_masks").is_dir())
    if not candidates:
        raise PredictionsError(f"{test}: no <iteration dir>/pred_masks/ folder (layout trase: {TRASE_PATTERN}; the "
                               "public render.py writes it when given --segment_ids)")
    numbered = {c: int(m.group(1)) for c in candidates if (m := _ITERATION.match(c))}
    if len(candidates) == 1:
        chosen = candidates[0]
    elif len(numbered) == len(candidates):
        chosen = max(numbered, key=numbered.get)
    else:
        raise PredictionsError(f"{test}: several folders with pred_masks ({', '.join(candidates)}) and not all "
                               "named ours_<iteration>: keep only the one to evaluate")
    masks = test / chosen / "pred_masks"
    if not _mask_files(masks):
        raise PredictionsError(f"{masks}: no mask files (layout trase: {TRASE_PATTERN})")
    others = tuple(c for c in candidates if c != chosen)
    return SequencePredictions(folder, masks, "trase", chosen, others)


def _mask_files(d: Path) -> list[Path]:
    return [p for p in d.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
