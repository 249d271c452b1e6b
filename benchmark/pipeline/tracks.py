"""Stage ``tracks``: ids consistent across the training views (masks.tracked), after ``geometry``.

Runs where ``masks.tracking`` is not ``none`` (a method that declares ``needs_tracks`` gets
``classical`` by default); otherwise it adds no stage and no key, so untracked runs are as
before. Its folder holds the masks stage's anything masks (hard links) beside the track ids and
``tracks.json``, and is the ``masks_dir`` the method's ``learn`` then receives. Sources:

- ``synthetic``: the synthetic scene's instance maps (the generator's ground truth), instance
  ids mapped to 1..K in ascending order; ``tracks.json`` source ``synthetic-truth``. A protocol
  of its own: ids from ground truth, never a tracker's;
- ``files``: per-frame id images a user brings (``masks.tracks_dir``; DEVA's output), ids mapped
  to 1..K in ascending order of the files' ids (``find_track_files``);
- ``classical``: the project's tracker over the anything masks (``track_classical``): each
  training view's masks become one segment per pixel (DEVA's rule), the views are taken in time
  order, and each view's segments take the ids of the previous view's tracks warped into it
  through the frozen geometry (depth and the gaussians' motion, ``trase.warp``), matched by IoU.

Keys: the tracking settings and the masks stage's key, plus the scene (synthetic), the files'
checksums (files), or the geometry stage's key and the tracker's constants (classical).
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections import Counter
from pathlib import Path

import numpy as np

from benchmark.cache import StageRecord
from benchmark.config import ConfigError
from benchmark.pipeline.context import SequenceRun, synthetic_truth

# -- the classical tracker's constants (recorded in tracks.json and keyed) -------------------
# a segment continues a track when their IoU (over the pixels the warp knows) is above one
# half: the lowest threshold at which a segment and a track each have at most one candidate, so
# a track never passes to the wrong one of two pieces of what it was
IOU_THRESHOLD = 0.5
# DEVA's SAM_OVERLAP_THRESHOLD (its default, 0.8): a mask that keeps less than this share of its
# pixels once larger masks took theirs is a part of them, not a segment of its own
MIN_KEPT = 0.8
# a segment left unmatched by the previous view is matched against the tracks of up to this many
# views before it (most recent first): DEVA keeps an object through 5 missed detections (its
# max_missed_detection_count default), and an object whose mask was split, merged with a
# neighbour or missed in one view comes back whole in the next
MEMORY = 5
# a segment still unmatched that lies (by at least this share of the pixels the warp knows) in
# one track of the previous view is a part of that object and takes its id (many parts may): the
# share DEVA's rule uses to call a mask part of a larger one (MIN_KEPT); a neighbour merged into
# the mask pushes the share towards one half, well below it
PART_OF = MIN_KEPT
# on a rig of fixed cameras the previous views are mostly other cameras at the same instant (a
# reprojection across the baseline); a segment left unmatched by the previous view is next
# sought in the same camera's latest view (the warp then carries only the motion between two
# instants), before the memory's earlier views
SAME_CAMERA = True
# after the last view, tracks whose views' votes fall on the same gaussians (cosine of their vote
# columns, masks.track_merging) at least this similar are merged, unless some view shows them
# side by side: chosen on the selection scenes (seed 1) by the agreement with their instance
# maps (docs/tracked-masks.md); None: no merging
MERGE_COSINE = 0.5
# ... unless the same views show them as two segments in more than this share of the views of the
# one seen in fewer (an object cut in two by its masks in a few views; two objects seen together
# share most of theirs); chosen with MERGE_COSINE
MERGE_MAX_TOGETHER = 0.1
# a track of the previous view that no segment of this view continues keeps the pixels the warp
# puts it on where no segment holds them or a neighbour's segment merged it (at most half of that
# segment), for up to this many views in a row: a video tracker's propagation keeps an object
# through missed detections (DEVA through 5, MEMORY), so a mask that merged an object with the
# floor in one view does not hand the object's pixels to the floor's track there; not where a
# segment of this view is mostly the track (its own mask, which started a new track), not into a
# segment that starts a new track (an object's new mask over its old fragments), and only tracks
# that segments held in two views at least (an object, not a one-view fragment); carried pixels
# are not "shown" for the merge (they are no mask), so fragments still merge; 0: not carried
CARRY = MEMORY
CARRY_MAX_SHARE = 0.5
CLASSICAL = {"iou_threshold": IOU_THRESHOLD, "min_kept": MIN_KEPT, "memory": MEMORY, "part_of": PART_OF,
             "same_camera": SAME_CAMERA, "merge_cosine": MERGE_COSINE, "merge_max_together": MERGE_MAX_TOGETHER,
             "carry": CARRY, "carry_max_share": CARRY_MAX_SHARE, "order": "time, then view name",
             "min_area": "the mask generators' minimum area (SAM's 100 px at 536x960, scaled)",
             "version": 8}

# where a DEVA output folder keeps its per-frame images: Annotations/ (demo_automatic.py and
# demo_with_text.py), object_mask/ (Gaussian Grouping's copy of it), else the folder itself
FILE_SUBDIRS = ("Annotations", "object_mask")
FILE_SUFFIXES = (".png",)


def run(ctx: SequenceRun) -> list[StageRecord]:
    settings = ctx.settings.masks
    if getattr(settings, "tracking", "none") == "none":
        return []
    masks_rec = ctx.records["masks"]
    cfg = {"tracking": settings.tracking}
    inputs = {"masks": masks_rec.key}
    if settings.tracking == "synthetic":
        inputs["scene"] = ctx.scene_key
    elif settings.tracking == "files":
        src = Path(settings.tracks_dir)
        cfg["tracks_dir"] = str(src)
        inputs["files"] = _files_key(ctx.scene.train, src)
    else:
        cfg["classical"] = CLASSICAL
        inputs["geometry"] = ctx.records["geometry"].key
    key = ctx.cache.key("tracks", cfg, inputs)

    def work(d: Path) -> dict:
        link_masks(ctx.scene.train, masks_rec.path, d)
        if settings.tracking == "synthetic":
            return write_synthetic(ctx.scene, d)
        if settings.tracking == "files":
            return write_files(ctx.scene.train, Path(settings.tracks_dir), d)
        gaussians, deformation = ctx.geometry
        return track_classical(ctx.scene.train, gaussians, deformation, d, truth=ctx.scene.truth,
                               progress=ctx.progress)

    return [ctx.cache.run("tracks", key, work, cfg)]


def link_masks(views, src: Path, out: Path) -> None:
    """The anything masks of every view beside the ids (hard links; copies where the file system
    has none), so one folder is the method's masks_dir."""
    import masks as masklib

    for v in views:
        a, b = masklib.mask_path(src, v.name), masklib.mask_path(out, v.name)
        b.unlink(missing_ok=True)
        try:
            os.link(a, b)
        except OSError:
            shutil.copy2(a, b)


def _check_size(path, ids: np.ndarray, view) -> None:
    from masks.tracked import TrackFileError

    want = (view.camera.height, view.camera.width)
    if ids.shape != want:
        raise TrackFileError(path, f"ids are {ids.shape[1]}x{ids.shape[0]} but training view {view.name} is "
                                   f"{want[1]}x{want[0]} (WxH)")


def _save_all(views, maps: list[np.ndarray], out: Path) -> None:
    from masks.tracked import ids_path, save_ids

    for v, ids in zip(views, maps):
        save_ids(ids_path(out, v.name), ids)


# -- synthetic: the generator's instance maps ---------------------------------------------------
def write_synthetic(scene, out: Path) -> dict:
    """Track ids from the synthetic scene's instance maps (ground truth)."""
    from masks.generate import read_instance_map
    from masks.tracked import remap_ids, save_tracks_info

    truth = synthetic_truth(scene)
    maps = []
    for v in scene.train:
        path = truth.instance_maps.get(v.name)
        if path is None:
            raise ConfigError(f"{truth.manifest_path}: no instance map for training view {v.name}")
        ids = read_instance_map(path)
        _check_size(path, ids, v)
        maps.append(ids)
    tracked, mapping = remap_ids(maps)
    _save_all(scene.train, tracked, out)
    names = {o.id: o.name for o in truth.objects}
    info = {"source": "synthetic-truth", "n_tracks": len(mapping), "views": len(scene.train),
            "instance_of_track": {str(k): i for i, k in mapping.items()},
            "name_of_track": {str(k): names.get(i, "") for i, k in mapping.items()}}
    save_tracks_info(out, info)
    return {"source": "synthetic-truth", "n_tracks": len(mapping)}


# -- files: a tracker's output a user brings ----------------------------------------------------
def files_root(src: Path) -> Path:
    """The folder of per-frame images in ``src``: its ``Annotations/`` or ``object_mask/`` where
    present (the first), else ``src`` itself."""
    if not src.is_dir():
        raise ConfigError(f"{src}: masks.tracks_dir is not a folder")
    return next((src / s for s in FILE_SUBDIRS if (src / s).is_dir()), src)


def _file_candidates(root: Path, view) -> list[Path]:
    """A view's id image in ``root``: named after the view (``/`` -> ``__``) or after its image
    (the image's path without its suffix, keeping up to its two parent folders, longest first;
    DEVA names each output after its input image), with a suffix of FILE_SUFFIXES."""
    parts = Path(view.image_path).with_suffix("").parts
    names = [view.name.replace("/", "__"), *("/".join(parts[-k:]) for k in (3, 2, 1) if len(parts) >= k)]
    names = list(dict.fromkeys(names))
    return [root / f"{n}{s}" for n in names for s in FILE_SUFFIXES]


def find_track_files(views, src: Path) -> tuple[Path, list[Path]]:
    """(the folder read, one id image per training view, in view order); a view without one is
    a one-line error naming where it was looked for."""
    root = files_root(src)
    found = []
    for v in views:
        cands = _file_candidates(root, v)
        hit = next((c for c in cands if c.is_file()), None)
        if hit is None:
            others = ", ".join(str(c.relative_to(root)) for c in cands[1:])
            raise ConfigError(f"{cands[0]}: no track ids for training view {v.name} in masks.tracks_dir (nor {others})")
        found.append(hit)
    return root, found


def _files_key(views, src: Path) -> str:
    from benchmark.io import sha256_files

    return sha256_files(find_track_files(views, src)[1])[:16]


def write_files(views, src: Path, out: Path) -> dict:
    """Track ids from per-frame id images (``masks.tracked.read_id_image``), remapped to 1..K."""
    from masks.tracked import read_id_image, remap_ids, save_tracks_info

    root, files = find_track_files(views, src)
    maps = []
    for v, f in zip(views, files):
        ids = read_id_image(f)
        _check_size(f, ids, v)
        maps.append(ids)
    tracked, mapping = remap_ids(maps)
    _save_all(views, tracked, out)
    info = {"source": "files", "n_tracks": len(mapping), "views": len(views), "tracks_dir": str(src),
            "read_from": str(root), "files": {v.name: str(f.relative_to(root)) for v, f in zip(views, files)},
            "id_in_files_of_track": {str(k): o for o, k in mapping.items()}}
    save_tracks_info(out, info)
    return {"source": "files", "n_tracks": len(mapping), "read_from": str(root)}


# -- classical: the project's tracker -----------------------------------------------------------
@contextlib.contextmanager
def _views_bar(total: int, shown: bool):
    """A rich progress bar over the tracked views (nothing where not ``shown``) -> advance(text)."""
    if not shown:
        yield lambda last: None
        return
    from rich import progress as rp

    bar = rp.Progress(rp.TextColumn("tracks"), rp.BarColumn(), rp.MofNCompleteColumn(), rp.TimeElapsedColumn(),
                      rp.TimeRemainingColumn(), rp.TextColumn("{task.fields[last]}"))
    task = bar.add_task("tracks", total=total, last="")
    with bar:
        yield lambda last: bar.update(task, advance=1, last=last)


def time_order(views) -> list:
    """The training views in time order (ties: by name, so the cameras of one instant follow
    one another in a fixed order)."""
    return sorted(views, key=lambda v: (float(v.camera.time), v.name))


def camera_key(camera) -> bytes:
    """What makes two views one fixed camera: the same intrinsics, pose and size."""
    return np.concatenate([np.round(np.asarray(camera.K, np.float64), 6).ravel(),
                           np.round(np.asarray(camera.w2c, np.float64), 6).ravel(),
                           [camera.width, camera.height]]).tobytes()


def track_classical(views, gaussians, deformation, out: Path, truth=None, memory: int = MEMORY,
                    part_of_share: float | None = PART_OF, same_camera: bool = SAME_CAMERA,
                    merge_cosine: float | None = MERGE_COSINE, merge_max_together: float = MERGE_MAX_TOGETHER,
                    carry: int = CARRY, votes=None, progress: bool = False) -> dict:
    """Track ids for the anything masks in ``out`` (one file per view, as the masks stage wrote
    them): per view in time order, segments (``segments_from_masks``), then the previous view's
    ids warped into this one (``trase.warp.backward_warp``), segments matched to the warped
    tracks one to one by IoU above IOU_THRESHOLD (Hungarian); segments still unmatched are
    matched in the same way against the tracks of the same camera's latest view (SAME_CAMERA: a
    rig of fixed cameras), then of up to MEMORY earlier views (most recent first), that no
    segment of this view continues; a segment unmatched after that which lies in one track of
    the previous view (PART_OF of its known pixels) is a part of it and takes its id; any other
    starts a new track. A track of the previous view that no segment continues keeps the pixels
    the warp puts it on where no segment, or a neighbour's that merged it, holds them
    (``masks.tracked.carry_lost``; CARRY views in a row at most). After the last view, tracks
    that are one object in 3D are merged (``masks.track_merging``: each view's votes for the
    gaussians it shows, MERGE_COSINE, MERGE_MAX_TOGETHER).
    ``truth`` (a synthetic scene's): the agreement with its instance maps is recorded.
    ``memory``, ``part_of_share`` (None: no parts), ``same_camera``, ``merge_cosine`` (None:
    no merging), ``merge_max_together`` and ``carry`` (0: nothing carried) change those steps
    for measurements (scripts/measure_tracking.py), which may pass a ``masks.track_merging.TrackVotes`` as
    ``votes`` to keep the views' votes; the stage uses the constants. ``progress``: a bar over
    the views (a large rig's take minutes)."""
    import masks as masklib
    from masks.generate import read_instance_map
    from masks.generators.base import min_area_for
    from masks.track_merging import TrackVotes, merged_ids, track_similarity
    from masks.tracked import (
        agreement,
        carry_lost,
        ids_path,
        iou_of,
        match_segments,
        overlap_counts,
        part_of,
        save_ids,
        save_tracks_info,
        segments_from_masks,
    )
    from trase.warp import backward_warp, view_geometry, visible_gaussians

    n_tracks = 0
    recent: list[tuple] = []  # (view geometry, ids) of the previous view and up to `memory` before it
    latest_of_camera: dict[bytes, tuple] = {}  # the same, of the latest view of each camera seen again later
    views_left = Counter(camera_key(v.camera) for v in views)  # a moving camera's views: 1 each
    continued = resumed = joined = started = carried = 0
    carried_for: Counter = Counter()  # track -> views in a row it has been carried
    segment_views: Counter = Counter()  # track -> views a segment of its own held it in
    maps = {}
    voting = merge_cosine is not None or votes is not None
    votes = TrackVotes(gaussians.num_gaussians) if votes is None else votes
    with _views_bar(len(views), progress) as advance:
        for v in time_order(views):
            path = masklib.mask_path(out, v.name)
            ms = masklib.load(path)
            if (ms.height, ms.width) != (v.camera.height, v.camera.width):
                raise masklib.MaskFileError(path, f"masks are {ms.width}x{ms.height} but training view {v.name} is "
                                                  f"{v.camera.width}x{v.camera.height} (WxH)")
            seg = segments_from_masks(ms.masks, MIN_KEPT, min_area_for(ms.height, ms.width))
            n_seg = int(seg.max())
            tracks_before = n_tracks
            geo = view_geometry(gaussians, deformation, v.camera)
            track_of = np.zeros(n_seg + 1, np.int64)
            last = None  # the previous view's overlaps, for the parts
            warped_last = None  # the previous view's ids warped into this one, for carrying
            key = camera_key(v.camera)
            candidates = list(reversed(recent))
            own = latest_of_camera.get(key) if same_camera else None
            if own is not None and not any(own is c for c in candidates):
                candidates.insert(1, own)  # after the previous view, before the memory
            for back, (prev, prev_ids) in enumerate(candidates):
                free = np.flatnonzero(track_of[1:] == 0)
                if not free.shape[0] or not n_tracks:
                    break
                warped = backward_warp(gaussians, deformation, prev, geo, prev_ids)
                counts = overlap_counts(seg, warped, n_seg, n_tracks)
                if back == 0:
                    last, warped_last = counts, warped
                iou = iou_of(counts)  # the same counts, not counted again
                iou[:, track_of[track_of > 0] - 1] = 0.0  # a track continues in one segment only
                match = match_segments(iou[free], IOU_THRESHOLD)
                for s, t in match.items():
                    track_of[free[s] + 1] = t + 1
                if back == 0:
                    continued += len(match)
                else:
                    resumed += len(match)
            free = np.flatnonzero(track_of[1:] == 0)
            if last is not None and free.shape[0] and part_of_share is not None:
                inter, known, _ = last
                area = np.bincount(seg.ravel(), minlength=n_seg + 1)[1:]
                parts = part_of(inter[free], known[free], area[free], part_of_share)
                for s, t in parts.items():
                    track_of[free[s] + 1] = t + 1
                joined += len(parts)
            for s in range(1, n_seg + 1):
                if track_of[s] == 0:
                    n_tracks += 1
                    track_of[s] = n_tracks
                    started += 1
            ids = track_of[seg].astype(np.int32)
            shown = track_of[1:]
            held = set(shown.tolist())  # a track with several parts here counts once
            segment_views.update(held)
            if carry > 0 and recent:
                if warped_last is None:  # no segment here, so the loop above warped nothing
                    warped_last = backward_warp(gaussians, deformation, recent[-1][0], geo, recent[-1][1])
                before = np.unique(recent[-1][1])
                lost = [int(t) for t in before[before > 0]
                        if int(t) not in held and carried_for[int(t)] < carry and segment_views[int(t)] >= 2]
                may_give = np.concatenate([[True], track_of[1:] <= tracks_before])  # not a new track's segment
                ids, kept = carry_lost(ids, seg, warped_last, lost, min_area_for(ms.height, ms.width),
                                       CARRY_MAX_SHARE, may_give)
                carried_for = Counter({t: carried_for[t] + 1 for t in kept})  # continued or dropped: reset
                carried += len(kept)
            maps[v.name] = ids
            if voting:
                votes.add(ids, *visible_gaussians(geo), present=shown)
            recent = [*recent, (geo, ids)][-(max(memory, 0) + 1):]  # the previous view and `memory` before it
            views_left[key] -= 1
            if views_left[key] > 0:
                latest_of_camera[key] = recent[-1]
            else:
                latest_of_camera.pop(key, None)  # its last view: kept no longer
            advance(f"{n_tracks} tracks")
    merged = {}
    if merge_cosine is not None and n_tracks > 1:
        vote_matrix, shown = votes.matrices(n_tracks)
        new_id = merged_ids(track_similarity(vote_matrix), shown, merge_cosine, merge_max_together)
        merged = {"tracks_before": n_tracks, "merged": n_tracks - int(new_id.max())}
        for ids in maps.values():
            ids[:] = new_id[ids]  # in place: a large rig's maps are not held twice
        n_tracks = int(new_id.max())
    for v in views:
        save_ids(ids_path(out, v.name), maps[v.name])
    constants = {**CLASSICAL, "memory": memory, "part_of": part_of_share, "same_camera": same_camera,
                 "merge_cosine": merge_cosine, "merge_max_together": merge_max_together, "carry": carry}
    info = {"source": "classical", "n_tracks": n_tracks, "views": len(views), "constants": constants,
            "continued": continued, "resumed": resumed, "parts": joined, "started": started,
            "carried": carried, **merged}
    if truth is not None:
        truth_maps = [read_instance_map(truth.instance_maps[v.name]) for v in views]
        info["agreement_with_truth"] = agreement([maps[v.name] for v in views], truth_maps)
    save_tracks_info(out, info)
    return {k: info[k] for k in ("source", "n_tracks", "continued", "resumed", "parts", "started", "carried",
                                 "tracks_before", "merged", "agreement_with_truth")
            if k in info}


__all__ = ["CARRY", "CARRY_MAX_SHARE", "CLASSICAL", "IOU_THRESHOLD", "MEMORY", "MERGE_COSINE",
           "MERGE_MAX_TOGETHER", "MIN_KEPT", "PART_OF", "SAME_CAMERA", "camera_key", "find_track_files",
           "link_masks", "run", "time_order", "track_classical", "write_files", "write_synthetic"]
