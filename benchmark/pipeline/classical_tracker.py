"""The classical tracker: ids for the anything masks of the training views, consistent across
views, from the frozen geometry (the tracks stage's ``classical`` source, benchmark.pipeline.tracks).

Per view in time order, each view's masks become one segment per pixel (DEVA's rule), the
previous views' ids are warped into it through the geometry (depth and the gaussians' motion,
``trase.warp``) and matched to its segments by IoU; what stays unmatched is a part of a track,
or a new one. After the last view, tracks that are one object in 3D are merged. The constants
below are recorded in ``tracks.json`` and keyed.
"""

from __future__ import annotations

import contextlib
from collections import Counter
from pathlib import Path

import numpy as np

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


class ClassicalTracker:
    """What the tracker carries from one view to the next: the tracks so far, the recent views'
    geometry and ids, and the counts ``tracks.json`` records. ``add_view`` takes the views in
    time order."""

    def __init__(self, views, gaussians, deformation, memory: int, part_of_share: float | None,
                 same_camera: bool, carry: int, votes=None):
        self.gaussians, self.deformation = gaussians, deformation
        self.memory, self.part_of_share, self.same_camera, self.carry = memory, part_of_share, same_camera, carry
        self.votes = votes  # masks.track_merging.TrackVotes, or None: no votes kept
        self.n_tracks = 0
        self.recent: list[tuple] = []  # (view geometry, ids) of the previous view and up to `memory` before it
        self.latest_of_camera: dict[bytes, tuple] = {}  # the same, of the latest view of each camera seen again later
        self.views_left = Counter(camera_key(v.camera) for v in views)  # a moving camera's views: 1 each
        self.counts = Counter(continued=0, resumed=0, parts=0, started=0, carried=0)
        self.carried_for: Counter = Counter()  # track -> views in a row it has been carried
        self.segment_views: Counter = Counter()  # track -> views a segment of its own held it in
        self.maps: dict[str, np.ndarray] = {}  # view name -> ids [H, W] int32

    def add_view(self, view, masks) -> None:
        """The ids of ``view`` from its anything masks (``masks.MaskSet``)."""
        from masks.generators.base import min_area_for
        from masks.tracked import segments_from_masks
        from trase.warp import view_geometry, visible_gaussians

        min_area = min_area_for(masks.height, masks.width)
        seg = segments_from_masks(masks.masks, MIN_KEPT, min_area)  # [H, W] segment per pixel, 0: none
        n_seg = int(seg.max())
        tracks_before = self.n_tracks
        geo = view_geometry(self.gaussians, self.deformation, view.camera)
        key = camera_key(view.camera)
        track_of = np.zeros(n_seg + 1, np.int64)  # segment -> track (1-based), 0: none yet
        last, warped_last = self._match_earlier_views(seg, n_seg, geo, key, track_of)
        self._join_parts(seg, n_seg, last, track_of)
        for s in range(1, n_seg + 1):
            if track_of[s] == 0:
                self.n_tracks += 1
                track_of[s] = self.n_tracks
                self.counts["started"] += 1
        ids = track_of[seg].astype(np.int32)
        held = set(track_of[1:].tolist())  # a track with several parts here counts once
        self.segment_views.update(held)
        if self.carry > 0 and self.recent:
            ids = self._carry_lost(ids, seg, geo, warped_last, held, track_of, tracks_before, min_area)
        self.maps[view.name] = ids
        if self.votes is not None:
            self.votes.add(ids, *visible_gaussians(geo), present=track_of[1:])
        self._remember(key, geo, ids)

    def _match_earlier_views(self, seg, n_seg: int, geo, key: bytes, track_of: np.ndarray):
        """Segments matched one to one to the tracks of the previous view, then of the same
        camera's latest view, then of the memory's (``track_of`` filled in place) -> (the
        previous view's overlap counts, its ids warped here), None where no view was warped."""
        from masks.tracked import iou_of, match_segments, overlap_counts
        from trase.warp import backward_warp

        last = warped_last = None
        candidates = list(reversed(self.recent))
        own = self.latest_of_camera.get(key) if self.same_camera else None
        if own is not None and not any(own is c for c in candidates):
            candidates.insert(1, own)  # after the previous view, before the memory
        for back, (prev, prev_ids) in enumerate(candidates):
            free = np.flatnonzero(track_of[1:] == 0)
            if not free.shape[0] or not self.n_tracks:
                break
            warped = backward_warp(self.gaussians, self.deformation, prev, geo, prev_ids)
            counts = overlap_counts(seg, warped, n_seg, self.n_tracks)
            if back == 0:
                last, warped_last = counts, warped
            iou = iou_of(counts)  # the same counts, not counted again
            iou[:, track_of[track_of > 0] - 1] = 0.0  # a track continues in one segment only
            match = match_segments(iou[free], IOU_THRESHOLD)
            for s, t in match.items():
                track_of[free[s] + 1] = t + 1
            self.counts["continued" if back == 0 else "resumed"] += len(match)
        return last, warped_last

    def _join_parts(self, seg, n_seg: int, last, track_of: np.ndarray) -> None:
        """A segment still unmatched that lies in one track of the previous view takes its id."""
        from masks.tracked import part_of

        free = np.flatnonzero(track_of[1:] == 0)
        if last is None or not free.shape[0] or self.part_of_share is None:
            return
        inter, known, _ = last
        area = np.bincount(seg.ravel(), minlength=n_seg + 1)[1:]
        parts = part_of(inter[free], known[free], area[free], self.part_of_share)
        for s, t in parts.items():
            track_of[free[s] + 1] = t + 1
        self.counts["parts"] += len(parts)

    def _carry_lost(self, ids, seg, geo, warped_last, held: set, track_of, tracks_before: int, min_area: int):
        """``ids`` with the previous view's tracks that no segment continues kept where the warp
        puts them (``masks.tracked.carry_lost``)."""
        from masks.tracked import carry_lost
        from trase.warp import backward_warp

        if warped_last is None:  # no segment here, so the matching warped nothing
            warped_last = backward_warp(self.gaussians, self.deformation, self.recent[-1][0], geo, self.recent[-1][1])
        before = np.unique(self.recent[-1][1])
        lost = [int(t) for t in before[before > 0]
                if int(t) not in held and self.carried_for[int(t)] < self.carry and self.segment_views[int(t)] >= 2]
        may_give = np.concatenate([[True], track_of[1:] <= tracks_before])  # not a new track's segment
        ids, kept = carry_lost(ids, seg, warped_last, lost, min_area, CARRY_MAX_SHARE, may_give)
        self.carried_for = Counter({t: self.carried_for[t] + 1 for t in kept})  # continued or dropped: reset
        self.counts["carried"] += len(kept)
        return ids

    def _remember(self, key: bytes, geo, ids) -> None:
        self.recent = [*self.recent, (geo, ids)][-(max(self.memory, 0) + 1):]  # the previous view and `memory` before it
        self.views_left[key] -= 1
        if self.views_left[key] > 0:
            self.latest_of_camera[key] = self.recent[-1]
        else:
            self.latest_of_camera.pop(key, None)  # its last view: kept no longer

    def merge(self, merge_cosine: float | None, merge_max_together: float) -> dict:
        """Tracks that are one object in 3D merged (``masks.track_merging``), the maps renumbered
        in place -> {tracks_before, merged}, empty where nothing was tried."""
        from masks.track_merging import merged_ids, track_similarity

        if merge_cosine is None or self.n_tracks <= 1:
            return {}
        vote_matrix, shown = self.votes.matrices(self.n_tracks)
        new_id = merged_ids(track_similarity(vote_matrix), shown, merge_cosine, merge_max_together)
        merged = {"tracks_before": self.n_tracks, "merged": self.n_tracks - int(new_id.max())}
        for ids in self.maps.values():
            ids[:] = new_id[ids]  # in place: a large rig's maps are not held twice
        self.n_tracks = int(new_id.max())
        return merged


def track_classical(views, gaussians, deformation, out: Path, truth=None, memory: int = MEMORY,
                    part_of_share: float | None = PART_OF, same_camera: bool = SAME_CAMERA,
                    merge_cosine: float | None = MERGE_COSINE, merge_max_together: float = MERGE_MAX_TOGETHER,
                    carry: int = CARRY, votes=None, progress: bool = False) -> dict:
    """Track ids for the anything masks in ``out`` (one file per view, as the masks stage wrote
    them), written beside them with ``tracks.json`` -> the summary the stage records.

    Per view in time order (``ClassicalTracker.add_view``): segments (``segments_from_masks``),
    then the previous view's ids warped into this one (``trase.warp.backward_warp``), segments
    matched to the warped tracks one to one by IoU above IOU_THRESHOLD (Hungarian); segments
    still unmatched are matched in the same way against the tracks of the same camera's latest
    view (SAME_CAMERA: a rig of fixed cameras), then of up to MEMORY earlier views (most recent
    first), that no segment of this view continues; a segment unmatched after that which lies in
    one track of the previous view (PART_OF of its known pixels) is a part of it and takes its
    id; any other starts a new track. A track of the previous view that no segment continues
    keeps the pixels the warp puts it on where no segment, or a neighbour's that merged it,
    holds them (``masks.tracked.carry_lost``; CARRY views in a row at most). After the last
    view, tracks that are one object in 3D are merged (``masks.track_merging``: each view's
    votes for the gaussians it shows, MERGE_COSINE, MERGE_MAX_TOGETHER).
    ``truth`` (a synthetic scene's): the agreement with its instance maps is recorded.
    ``memory``, ``part_of_share`` (None: no parts), ``same_camera``, ``merge_cosine`` (None:
    no merging), ``merge_max_together`` and ``carry`` (0: nothing carried) change those steps
    for measurements (scripts/measure_tracking.py), which may pass a ``masks.track_merging.TrackVotes``
    as ``votes`` to keep the views' votes; the stage uses the constants. ``progress``: a bar
    over the views (a large rig's take minutes)."""
    import masks as masklib
    from masks.generate import read_instance_map
    from masks.track_merging import TrackVotes
    from masks.tracked import agreement, ids_path, save_ids, save_tracks_info

    if votes is None and merge_cosine is not None:
        votes = TrackVotes(gaussians.num_gaussians)
    tracker = ClassicalTracker(views, gaussians, deformation, memory, part_of_share, same_camera, carry, votes)
    with _views_bar(len(views), progress) as advance:
        for v in time_order(views):
            path = masklib.mask_path(out, v.name)
            ms = masklib.load(path)
            if (ms.height, ms.width) != (v.camera.height, v.camera.width):
                raise masklib.MaskFileError(path, f"masks are {ms.width}x{ms.height} but training view {v.name} is "
                                                  f"{v.camera.width}x{v.camera.height} (WxH)")
            tracker.add_view(v, ms)
            advance(f"{tracker.n_tracks} tracks")
    merged = tracker.merge(merge_cosine, merge_max_together)
    for v in views:
        save_ids(ids_path(out, v.name), tracker.maps[v.name])
    constants = {**CLASSICAL, "memory": memory, "part_of": part_of_share, "same_camera": same_camera,
                 "merge_cosine": merge_cosine, "merge_max_together": merge_max_together, "carry": carry}
    info = {"source": "classical", "n_tracks": tracker.n_tracks, "views": len(views), "constants": constants,
            **tracker.counts, **merged}
    if truth is not None:
        truth_maps = [read_instance_map(truth.instance_maps[v.name]) for v in views]
        info["agreement_with_truth"] = agreement([tracker.maps[v.name] for v in views], truth_maps)
    save_tracks_info(out, info)
    return {k: info[k] for k in ("source", "n_tracks", "continued", "resumed", "parts", "started", "carried",
                                 "tracks_before", "merged", "agreement_with_truth")
            if k in info}


__all__ = ["CARRY", "CARRY_MAX_SHARE", "CLASSICAL", "IOU_THRESHOLD", "MEMORY", "MERGE_COSINE",
           "MERGE_MAX_TOGETHER", "MIN_KEPT", "PART_OF", "SAME_CAMERA", "ClassicalTracker", "camera_key",
           "time_order", "track_classical"]
