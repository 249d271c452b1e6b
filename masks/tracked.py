"""Tracked masks: per training view, one map of track ids that mean the same object in every view.

"Anything" masks (``masks.store``) carry no identity across images; methods that classify
identities (Gaussian Grouping, SA4D) need ids that are consistent over the whole sequence. They
are stored beside the anything masks of the same folder:

    <masks_dir>/<view name, '/' -> '__'>.ids.png   16-bit single-channel PNG of track ids
    <masks_dir>/tracks.json                        {"source": ..., "n_tracks": K, ...}

A pixel's value is 0 where it belongs to no track (background, or a region no track covers),
and 1..K elsewhere; track k is the same object in every view of the sequence. ``tracks.json``
says where the ids came from (``source``: ``synthetic-truth``, ``files`` or ``classical``), how
many there are, and per source what was read or decided.

Here: the storage (``ids_path``, ``save_ids``, ``load_ids``, ``save_tracks_info``,
``load_tracks_info``), the id maps of tracking files a user brings (``read_id_image``: DEVA's
outputs, ``remap_ids``), and the two geometry-free parts of the project's classical tracker
(``segments_from_masks``: one label per pixel from overlapping masks; ``match_segments``: the
assignment of a frame's segments to the tracks warped into it; ``carry_lost``: a track no
segment continues, kept where the warp puts it). Every problem with a file is a
``TrackFileError`` whose one-line message names the file.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from masks.maskset import MaskError
from masks.store import SUFFIX as MASKS_SUFFIX
from masks.store import MaskFileError, atomic_write, mask_path

IDS_SUFFIX = ".ids.png"
INFO_FILE = "tracks.json"
SOURCES = ("synthetic-truth", "files", "classical")
MAX_TRACKS = 65535  # what a 16-bit PNG holds (0 is "no track")


class TrackFileError(MaskFileError):
    """A track-id file (or tracks.json) that cannot be read or written; names the file."""


# ----------------------------------------------------------------------------- storage
def ids_path(masks_dir: os.PathLike | str, view_name: str) -> Path:
    """Where a view's track ids live: ``masks_dir/<view name, '/' -> '__'>.ids.png`` (the stem
    of ``masks.mask_path`` with another suffix)."""
    masks = mask_path(masks_dir, view_name)
    return masks.with_name(masks.name[: -len(MASKS_SUFFIX)] + IDS_SUFFIX)


def save_ids(path: os.PathLike | str, ids: np.ndarray) -> Path:
    """Write ``ids`` [H, W] (integers in 0..65535) as a 16-bit PNG, atomically (a temp file
    renamed over ``path``: a half-written file never exists)."""
    import cv2

    a = np.asarray(ids)
    if a.ndim != 2 or not np.issubdtype(a.dtype, np.integer):
        raise TrackFileError(path, f"track ids must be a 2D integer array, got {a.dtype} {a.shape}")
    if a.size and (a.min() < 0 or a.max() > MAX_TRACKS):
        raise TrackFileError(path, f"track ids must lie in 0..{MAX_TRACKS}, got {a.min()}..{a.max()}")
    ok, buf = cv2.imencode(".png", a.astype(np.uint16))
    if not ok:
        raise TrackFileError(path, "cannot encode the track ids as PNG")
    atomic_write(path, buf.tobytes())
    return Path(path)


def load_ids(path: os.PathLike | str) -> np.ndarray:
    """[H, W] int32 track ids of a file ``save_ids`` wrote; a missing, unreadable or
    non-16-bit file is a one-line ``TrackFileError`` naming it."""
    import cv2

    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise TrackFileError(path, "no such track-id file") from None
    except OSError as exc:
        raise TrackFileError(path, f"cannot read ({type(exc).__name__}: {exc})") from None
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    if img is None:
        raise TrackFileError(path, "not a readable PNG (corrupt or truncated track-id file)")
    if img.ndim != 2 or img.dtype != np.uint16:
        chans = 1 if img.ndim == 2 else img.shape[2]
        raise TrackFileError(path, f"expected a 16-bit single-channel PNG of track ids, got {img.dtype} with "
                                   f"{chans} channel(s)")
    return img.astype(np.int32)


def save_tracks_info(masks_dir: os.PathLike | str, info: dict) -> Path:
    """Write ``tracks.json`` (atomically); ``info`` holds at least ``source`` and ``n_tracks``."""
    path = Path(masks_dir) / INFO_FILE
    if info.get("source") not in SOURCES:
        raise TrackFileError(path, f"source must be one of {', '.join(SOURCES)}, got {info.get('source')!r}")
    if not isinstance(info.get("n_tracks"), int) or info["n_tracks"] < 0:
        raise TrackFileError(path, f"n_tracks must be a whole number >= 0, got {info.get('n_tracks')!r}")
    atomic_write(path, (json.dumps(info, indent=1, sort_keys=True) + "\n").encode())
    return path


def load_tracks_info(masks_dir: os.PathLike | str) -> dict:
    """The ``tracks.json`` of a masks folder: ``source``, ``n_tracks`` and the source's notes."""
    path = Path(masks_dir) / INFO_FILE
    try:
        info = json.loads(path.read_text())
    except FileNotFoundError:
        raise TrackFileError(path, "no tracks.json: this masks folder holds no tracked masks "
                                   "(set masks.tracking, or declare Method.needs_tracks)") from None
    except (OSError, ValueError) as exc:
        raise TrackFileError(path, f"cannot read tracks.json ({type(exc).__name__}: {exc})") from None
    if not isinstance(info, dict) or info.get("source") not in SOURCES or not isinstance(info.get("n_tracks"), int):
        raise TrackFileError(path, "tracks.json must be an object with source (one of "
                                   f"{', '.join(SOURCES)}) and n_tracks (a whole number)")
    return info


# ------------------------------------------------------------------ ids a user brings
def read_id_image(path: os.PathLike | str) -> np.ndarray:
    """[H, W] int64 object ids of one frame of a tracker's output, by the file's own encoding:

    - single channel, 8 or 16 bits (PNG mode ``L``/``I;16``): the value is the id (DEVA with
      ``--use_short_id``, what Gaussian Grouping trains from);
    - palette (mode ``P``): the palette *index* is the id, never the colour (DAVIS-style
      annotations, DEVA's short ids saved with a palette);
    - RGB(A): id = R + 256 G + 65536 B (DEVA's long ids, its demo default; ``pano_utils``'
      ``id_to_rgb``); alpha is ignored.
    0 is no object in every encoding."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            a = np.asarray(im)
    except FileNotFoundError:
        raise TrackFileError(path, "no such file") from None
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise TrackFileError(path, f"cannot read the id image ({type(exc).__name__}: {exc})") from None
    if mode in ("L", "P", "I;16", "I;16B", "I;16L", "I") and a.ndim == 2:
        if a.size and a.min() < 0:
            raise TrackFileError(path, "negative ids")
        return a.astype(np.int64)
    if mode in ("RGB", "RGBA") and a.ndim == 3:
        a = a[..., :3].astype(np.int64)
        return a[..., 0] + 256 * a[..., 1] + 65536 * a[..., 2]
    raise TrackFileError(path, f"cannot read ids from a PNG of mode {mode} (give one channel of ids, a palette "
                               "image or DEVA's RGB-encoded ids)")


def remap_ids(id_maps: list[np.ndarray]) -> tuple[list[np.ndarray], dict[int, int]]:
    """Ids of a whole sequence -> 1..K in ascending order of the original ids (0 stays 0), one
    mapping for every map, so an id means the same object in every view as it did in the
    input. -> (remapped maps as int32, {original id: track id})."""
    present = np.unique(np.concatenate([np.unique(m) for m in id_maps])) if id_maps else np.zeros(0, np.int64)
    present = present[present > 0]
    if present.shape[0] > MAX_TRACKS:
        raise MaskError(f"{present.shape[0]} distinct ids; a 16-bit track map holds at most {MAX_TRACKS}")
    mapping = {int(o): k + 1 for k, o in enumerate(present)}
    out = []
    for m in id_maps:
        r = np.zeros(m.shape, np.int32)
        if present.shape[0]:
            pos = np.searchsorted(present, m)
            hit = (m > 0) & (pos < present.shape[0])
            hit[hit] = present[pos[hit]] == m[hit]
            r[hit] = pos[hit] + 1
        out.append(r)
    return out, mapping


# ------------------------------------------------------------- the classical tracker's parts
def segments_from_masks(masks: np.ndarray, min_kept: float = 0.8, min_area: int = 1) -> np.ndarray:
    """[H, W] int32 labels 1..S (0: no mask) from overlapping masks [N, H, W], by DEVA's rule for
    SAM's automatic masks with ``--suppress_small_objects`` (what Gaussian Grouping runs): every
    pixel goes to the largest mask covering it, and a mask that keeps less than ``min_kept`` of
    its area that way (mostly eaten by larger ones; DEVA's SAM_OVERLAP_THRESHOLD) or fewer than
    ``min_area`` pixels gets no segment, and the pixels it did keep are left at 0, as DEVA leaves
    them. Labels are numbered by mask area, largest first."""
    m = np.asarray(masks, bool)
    if m.ndim != 3:
        raise MaskError(f"masks must be [N, H, W], got shape {m.shape}")
    n, h, w = m.shape
    labels = np.zeros((h, w), np.int32)
    if n == 0:
        return labels
    area = m.reshape(n, -1).sum(1)
    order = np.argsort(-area, kind="stable")
    owner = np.full((h, w), -1, np.int64)
    for i in order[::-1]:  # smallest first, so larger masks paint over them: the largest wins
        owner[m[i]] = i
    nxt = 1
    for i in order:
        kept = owner == i
        k = int(kept.sum())
        if area[i] == 0 or k < max(1, min_area) or k < min_kept * area[i]:
            continue
        labels[kept] = nxt
        nxt += 1
    return labels


def overlap_counts(segments: np.ndarray, warped: np.ndarray, n_segments: int,
                   n_tracks: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(intersections [S, T], each segment's known pixels [S], each warped track's pixels [T]),
    counted over the pixels where the warp is known (``warped >= 0``): pixels the previous
    frame could not see say nothing about either. ``segments`` holds labels 0..S, ``warped``
    -1 (unknown), 0 (no track) or a track id 1..T."""
    known = warped >= 0
    s = segments[known].astype(np.int64)
    t = warped[known].astype(np.int64)
    joint = np.bincount(s * (n_tracks + 1) + t, minlength=(n_segments + 1) * (n_tracks + 1))
    joint = joint.reshape(n_segments + 1, n_tracks + 1)
    return joint[1:, 1:].astype(np.float64), joint[1:, :].sum(1), joint[:, 1:].sum(0)


def overlap_iou(segments: np.ndarray, warped: np.ndarray, n_segments: int, n_tracks: int) -> np.ndarray:
    """[S, T] IoU of each segment (labels 1..S) with each warped track (1..T) over the pixels
    where the warp is known (``overlap_counts``)."""
    return iou_of(overlap_counts(segments, warped, n_segments, n_tracks))


def iou_of(counts: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """[S, T] IoU from ``overlap_counts``' (intersections, segments' known pixels, tracks' pixels)."""
    inter, s_area, t_area = counts
    union = s_area[:, None] + t_area[None, :] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def part_of(inter: np.ndarray, known: np.ndarray, area: np.ndarray, min_inside: float,
            min_known: float = 0.5) -> dict[int, int]:
    """{segment index: track index} for segments that are a part of one warped track: at least
    ``min_inside`` of their known pixels inside it, and at least ``min_known`` of their pixels
    known (``overlap_counts``' ``inter`` and ``known``; ``area`` [S] each segment's pixels).
    Many parts may join one track (an object whose mask came split)."""
    out = {}
    if inter.size == 0:
        return out
    best = inter.argmax(1)
    for s, t in enumerate(best.tolist()):
        if known[s] >= min_known * area[s] and known[s] > 0 and inter[s, t] >= min_inside * known[s]:
            out[s] = t
    return out


def carry_lost(ids: np.ndarray, segments: np.ndarray, warped: np.ndarray, lost, min_area: int,
               max_share: float = 0.5, may_give: np.ndarray | None = None) -> tuple[np.ndarray, list[int]]:
    """(ids [H, W] with lost tracks carried on, the ids carried): a track of the previous view
    that no segment of this view continues (``lost``) keeps the pixels it warps to (``warped``,
    -1 where unknown) that no segment holds (its mask was missed or eaten by a larger one) or
    that make at most ``max_share`` of the segment holding them (a neighbour's mask that merged
    it: the segment keeps its own track on the rest), as a video tracker's propagation keeps an
    object through missed detections; with fewer than ``min_area`` such pixels it is not carried.
    A track that makes more than ``max_share`` of some segment is not carried at all: that
    segment is the object's own mask, which started a track of its own (matching and the parts
    rule found it too different), and carrying the old one beside it would keep both.
    ``may_give`` [S + 1] bool: the segments that may give pixels (default all); the caller keeps
    a segment that started a new track whole (an object's new mask over its old fragments)."""
    out = ids.copy()
    carried = []
    if not len(lost):
        return out, carried
    n_seg = int(segments.max())
    area = np.bincount(segments.ravel(), minlength=n_seg + 1)
    for t in lost:
        px = warped == t
        if not px.any():
            continue
        inside = np.bincount(segments[px], minlength=n_seg + 1)
        share = np.divide(inside, area, out=np.zeros(n_seg + 1), where=area > 0)
        if (share[1:] > max_share).any():
            continue
        take = px & (out == ids)  # a pixel another lost track took stays its
        if may_give is not None:
            take &= np.asarray(may_give, bool)[segments]
        if int(take.sum()) < max(1, min_area):
            continue
        out[take] = t
        carried.append(int(t))
    return out, carried


def match_segments(iou: np.ndarray, threshold: float) -> dict[int, int]:
    """One-to-one assignment of segments (rows) to tracks (columns) maximising the summed IoU
    (Hungarian; scipy's linear_sum_assignment), keeping pairs with IoU above ``threshold`` ->
    {segment index: track index} (0-based). Above 0.5 a segment and a track each have at most
    one partner (two disjoint segments cannot both cover more than half of one track), so the
    assignment is then the greedy one too."""
    from scipy.optimize import linear_sum_assignment

    if iou.size == 0:
        return {}
    rows, cols = linear_sum_assignment(iou, maximize=True)
    return {int(r): int(c) for r, c in zip(rows, cols) if iou[r, c] > threshold}


def _track_votes(track_maps: list[np.ndarray], truth_maps: list[np.ndarray]):
    """({track: {true id: pixels}} over the sequence, the same per view); track 0 ("no track") left out."""
    votes: dict[int, dict[int, int]] = {}
    per_view = []
    for ids, truth in zip(track_maps, truth_maps):
        sel = ids > 0
        pairs, counts = np.unique(np.stack([ids[sel].astype(np.int64), truth[sel].astype(np.int64)]),
                                  axis=1, return_counts=True)
        view: dict[int, dict[int, int]] = {}
        for (k, t), c in zip(pairs.T.tolist(), counts.tolist()):
            view.setdefault(k, {})[t] = c
            votes.setdefault(k, {})
            votes[k][t] = votes[k].get(t, 0) + c
        per_view.append(view)
    return votes, per_view


def track_objects(track_maps: list[np.ndarray], truth_maps: list[np.ndarray]) -> dict[int, int]:
    """{track id: its true object}: the true id holding most of the track's pixels over the
    sequence (ties to the lower id), as ``agreement`` assigns them."""
    votes, _ = _track_votes(track_maps, truth_maps)
    return _majority(votes)


def _majority(votes: dict[int, dict[int, int]]) -> dict[int, int]:
    """{key: the id with most pixels in its votes} (ties to the id counted first)."""
    return {k: max(v, key=v.get) for k, v in votes.items()}


def agreement(track_maps: list[np.ndarray], truth_maps: list[np.ndarray]) -> dict:
    """How well track ids agree with true instance ids over a sequence (maps aligned per view):

    - ``masks``: the fraction of tracked masks (a track in one view) whose own majority true id
      is its track's majority true id over the whole sequence (a track that jumps to another
      object in some views loses those views);
    - ``pixels``: the same weighted by pixels (tracked pixels whose true id is their track's);
    - ``tracks_per_object``: tracks per true object (their majority), 1 where nothing fragments;
    - ``main_track_pixels``: per object, the share of its tracks' pixels in its largest track,
      averaged over the objects (1 where nothing fragments; a fragment of a few pixels costs
      little here and a whole track in ``tracks_per_object``);
    - ``n_masks``, ``n_tracks``, ``n_objects``."""
    votes, per_view = _track_votes(track_maps, truth_maps)
    major = _majority(votes)
    n_masks = sum(len(v) for v in per_view)
    right = sum(own == major[k] for view in per_view for k, own in _majority(view).items())
    total_px = sum(sum(v.values()) for v in votes.values())
    right_px = sum(v[major[k]] for k, v in votes.items())
    objects = set(major.values())
    track_px: dict[int, list[int]] = {}
    for k, v in votes.items():
        track_px.setdefault(major[k], []).append(sum(v.values()))
    main = [max(p) / sum(p) for p in track_px.values() if sum(p) > 0]
    return {"masks": right / n_masks if n_masks else 0.0, "pixels": right_px / total_px if total_px else 0.0,
            "tracks_per_object": len(major) / len(objects) if objects else 0.0,
            "main_track_pixels": float(np.mean(main)) if main else 0.0,
            "n_masks": n_masks, "n_tracks": len(major), "n_objects": len(objects)}


__all__ = [
    "IDS_SUFFIX",
    "INFO_FILE",
    "MAX_TRACKS",
    "SOURCES",
    "TrackFileError",
    "agreement",
    "carry_lost",
    "ids_path",
    "iou_of",
    "load_ids",
    "load_tracks_info",
    "match_segments",
    "overlap_counts",
    "overlap_iou",
    "part_of",
    "read_id_image",
    "remap_ids",
    "save_ids",
    "save_tracks_info",
    "segments_from_masks",
    "track_objects",
]
