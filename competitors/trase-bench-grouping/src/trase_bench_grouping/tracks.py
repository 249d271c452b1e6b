"""Tracked masks: per training view a 16-bit PNG of track ids (0 = no track, 1..K = one object
across views) beside the view's anything-masks, ``<masks_dir>/<stem>.ids.png``.

``masks.tracked`` owns the format where this trase-bench has it; this module reads the same
files otherwise, so the methods work with either.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

try:  # trase-bench's own reader, where this version has it
    from masks.tracked import ids_path, load_ids  # type: ignore[import-not-found]
except ImportError:  # the same file format, read here
    IDS_SUFFIX = ".ids.png"

    def ids_path(masks_dir, view_name: str) -> Path:
        """Where a view's track ids lie: beside its masks, ``<stem>.ids.png``."""
        from masks import mask_path

        p = mask_path(masks_dir, view_name)
        return p.with_name(p.name[: -len(p.suffix)] + IDS_SUFFIX) if p.suffix else p.with_name(p.name + IDS_SUFFIX)

    def load_ids(path) -> np.ndarray:
        """[H, W] int32 track ids of one view (0: no track); a one-line error naming the file."""
        import cv2

        from benchmark.methods import MethodError

        ids = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if ids is None:
            raise MethodError(f"{path}: cannot read tracked ids (a 16-bit PNG)")
        if ids.ndim != 2:
            raise MethodError(f"{path}: tracked ids must be one channel, got shape {ids.shape}")
        return ids.astype(np.int32)


def write_ids(masks_dir, view_name: str, ids: np.ndarray) -> Path:
    """Write one view's ids as the tracked-masks format has them (tests and tools)."""
    import cv2

    p = ids_path(masks_dir, view_name)
    p.parent.mkdir(parents=True, exist_ok=True)
    ids = np.asarray(ids)
    if ids.min(initial=0) < 0 or ids.max(initial=0) > 65535:
        raise ValueError(f"{p}: track ids must lie in 0..65535")
    if not cv2.imwrite(str(p), ids.astype(np.uint16)):
        raise OSError(f"{p}: cannot write PNG")
    return p


def write_tracks_json(masks_dir, source: str, n_tracks: int) -> Path:
    p = Path(masks_dir) / "tracks.json"
    p.write_text(json.dumps({"source": source, "n_tracks": int(n_tracks)}) + "\n")
    return p


def read_tracks_json(masks_dir) -> dict:
    p = Path(masks_dir) / "tracks.json"
    return json.loads(p.read_text()) if p.is_file() else {}


__all__ = ["ids_path", "load_ids", "read_tracks_json", "write_ids", "write_tracks_json"]
