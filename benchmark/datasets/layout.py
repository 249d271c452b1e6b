"""Where a sequence and its ground truth live on disk.

A scene lives at ``<data_root>/<dataset_key>/<sequence>/`` in the publisher's layout (a
HyperNeRF scene may sit one level deeper, e.g. ``hypernerf/interp/americano``), or in the form
``trase-bench prepare`` writes (``<scene>/prepared/`` is looked at too). Ground truth is
``<scene_dir>/gt_masks/{idx:05d}.png`` if present, else the Mask-Benchmark layout
``<data_root>/<DisplayName>/<sequence>/gt_masks/``; idx is the position in the test-view list.
Subdirectories of ``gt_masks`` (per-object ground truth) are ignored when aligning frames.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from benchmark.datasets.errors import fail
from benchmark.datasets.registry import get_dataset

_GT_NAME = re.compile(r"^(\d{5})\.png$")


def data_root(given: Path | str | None) -> Path | None:
    """The root of the real data: ``given`` (``--data-root``), else ``$TRASE_DATA``, else None.
    A root named but missing is an error: without it a run would silently use the built-in
    synthetic scene in place of the data the user meant."""
    if given is not None:
        root, named = Path(given), "--data-root"
    elif os.environ.get("TRASE_DATA"):
        root, named = Path(os.environ["TRASE_DATA"]), "$TRASE_DATA"
    else:
        return None
    if not root.is_dir():
        raise fail(root, f"no such directory (the data root given by {named})")
    return root


def find_scene_dir(dataset: str, sequence: str, data_root: Path | str) -> Path | None:
    """The directory of ``sequence`` under ``data_root``, or None if it is not there."""
    spec = get_dataset(dataset)
    root = Path(data_root)
    for base in (root / spec.key, root / spec.display_name, root):
        if not base.is_dir():
            continue
        for name in spec.folder_names(sequence):
            if (base / name).is_dir():
                return base / name
            nested = sorted(p for p in base.glob(f"*/{name}") if p.is_dir())
            if nested:
                return nested[0]
    return None


def find_gt_dir(
    dataset: str,
    sequence: str,
    data_root: Path | str | None = None,
    scene_dir: Path | str | None = None,
) -> Path | None:
    """The ``gt_masks`` directory for a sequence, or None when none exists.

    Looks in ``scene_dir/gt_masks`` (and its parent's, for a ``prepared`` folder), then in
    ``<data_root>/<DisplayName>/<sequence>/gt_masks`` for every folder name of the sequence.
    """
    spec = get_dataset(dataset)
    candidates: list[Path] = []
    if scene_dir is not None:
        scene_dir = Path(scene_dir)
        candidates += [scene_dir / "gt_masks", scene_dir.parent / "gt_masks"]
    roots = [Path(data_root)] if data_root is not None else []
    if scene_dir is not None and data_root is None:
        roots += [p for p in list(scene_dir.parents)[:3]]
    names = spec.folder_names(sequence) if sequence in spec.sequences or any(
        sequence in a for a in spec.aliases.values()) else (sequence,)  # e.g. a synthetic scene
    for root in roots:
        for name in names:
            candidates.append(root / spec.display_name / name / "gt_masks")
    for c in candidates:
        if c.is_dir():
            return c
    return None


def align_gt(gt_dir: Path, n_test: int) -> list[Path]:
    """``gt_dir/{idx:05d}.png`` for idx = 0..n_test-1; a missing or extra frame is an error."""
    gt_dir = Path(gt_dir)
    found: dict[int, Path] = {}
    for p in gt_dir.iterdir():
        if p.is_dir() or p.name.startswith("."):
            continue  # per-object ground truth lives in subdirectories
        m = _GT_NAME.match(p.name)
        if not m:
            raise fail(p, "unexpected file in gt_masks (expected {idx:05d}.png)")
        found[int(m.group(1))] = p
    missing = [i for i in range(n_test) if i not in found]
    extra = sorted(i for i in found if i >= n_test)
    if missing:
        raise fail(gt_dir, f"missing ground-truth frame(s) {_fmt(missing)} for {n_test} test views")
    if extra:
        raise fail(gt_dir, f"extra ground-truth frame(s) {_fmt(extra)}: only {n_test} test views")
    return [found[i] for i in range(n_test)]


def _fmt(idx: list[int]) -> str:
    shown = ", ".join(f"{i:05d}.png" for i in idx[:5])
    return shown + (f" ... ({len(idx)} in all)" if len(idx) > 5 else "")
