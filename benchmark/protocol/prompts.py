"""The benchmark's prompts: deterministic clicks from the test frames' ground truth.

Deterministic clicks from the test frames' ground truth, one per connected
  object region of at least ``min_area`` pixels, at the region's distance-transform maximum
  (the most interior pixel; ties broken by row-major order), made in that region's own frame.
  Rule ``gt-first-appearance`` (default): every region of the first non-empty frame, then each
  region of a later frame that touches no pixel that was object in any earlier test frame
  (within ``link_radius`` px): an object that enters later gets a click in the first frame it
  appears in, as a person clicking the objects of interest would. Linking to every earlier
  frame, not only the one before, keeps an object that was hidden for a while, or cut into
  slivers by an occluder, from being taken for a new one (synthetic HyperNeRF, reconstructed
  geometry: linked to the previous frame only, a 3-px sliver of an occluded object and an
  object back after one hidden frame got clicks, which added a background cluster: mIoU 0.13
  against the oracle's 0.74).
  Missed: a new object that enters where an object has been (the ground truth is one merged
  mask per frame: no identities).
  Rule ``gt-first-frame``: the first non-empty frame's regions only (the rule before prompts
  file version 2).
  Click sets (robustness): set 0 is the clicks above; set j >= 1 clicks the same objects
  elsewhere: in the (j-1) % 3-th frame of the object's first three (followed frame to frame by
  the largest overlap; the last one found when it is seen fewer times), at a pixel drawn (seed
  j, object k) from the region's interior half (distance-transform value >= half its
  maximum). A score per click set shows how much a result owes to where the automatic click
  fell.
  Saved to prompts.json and reused.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from trase.io import atomic_write_text
from trase.prompts import Click, PromptError

PROMPTS_VERSION = 3  # 2: each click names its own test frame; 3: new objects linked to every earlier frame
BENCHMARK_RULES = ("gt-first-appearance", "gt-first-frame")


def mask_regions(gt: np.ndarray, min_area: int, keep_largest: bool = True) -> list[tuple[int, float, float, np.ndarray]]:
    """(area, u, v, region mask) per connected region of gt [H, W] with >= min_area pixels,
    (u, v) the pixel centre of its distance-transform maximum (ties: first in row-major
    order), largest region first. With only smaller regions, ``keep_largest`` keeps the
    largest one anyway."""
    import cv2

    gt = np.asarray(gt, dtype=bool)
    if not gt.any():
        return []
    n, lab, stats, _ = cv2.connectedComponentsWithStats(gt.astype(np.uint8), connectivity=8)
    padded = np.pad(gt, 1).astype(np.uint8)  # image border counts as background
    dist = cv2.distanceTransform(padded, cv2.DIST_L2, 5)[1:-1, 1:-1]
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = [k for k in range(1, n) if areas[k - 1] >= min_area]
    if not keep and keep_largest:
        keep = [int(np.argmax(areas)) + 1]
    regions = []
    for k in keep:
        region = lab == k
        d = np.where(region, dist, -1.0)
        r, c = divmod(int(np.argmax(d)), gt.shape[1])  # first maximum in row-major order
        regions.append((int(areas[k - 1]), float(c) + 0.5, float(r) + 0.5, region))
    regions.sort(key=lambda x: (-x[0], x[2], x[1]))
    return regions


def interior_points(gt: np.ndarray, min_area: int = 20) -> list[tuple[float, float]]:
    """One (u, v) per connected region of gt [H, W] with >= min_area pixels (the largest
    region when all are smaller): its most interior pixel centre, largest region first."""
    return [(u, v) for _, u, v, _ in mask_regions(gt, min_area)]


@dataclasses.dataclass
class BenchmarkPrompts:
    view_index: int  # the first prompted test frame (index into the scene's test views)
    view: str  # its name
    time: float
    clicks: list[Click]  # each names its own frame (Click.view, view_index, time)
    source: str = "gt-first-appearance"  # the rule that made them (BENCHMARK_RULES)
    # click sets 1.. (module docstring): alternatives[j - 1][k] clicks the object of clicks[k]
    alternatives: list[list[Click]] = dataclasses.field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "version": PROMPTS_VERSION, "source": self.source, "view_index": self.view_index,
            "view": self.view, "time": self.time,
            "clicks": [click_dict(c) for c in self.clicks],
            "alternatives": [[click_dict(c) for c in clicks] for clicks in self.alternatives],
        }

    @classmethod
    def from_dict(cls, d: dict, path: str = "prompts.json") -> BenchmarkPrompts:
        try:
            if int(d["version"]) != PROMPTS_VERSION:
                raise PromptError(f"{path}: prompts version {d['version']} (expected {PROMPTS_VERSION}); "
                                  "delete it to make it again")
            clicks = [_click_from(c) for c in d["clicks"]]
            alternatives = [[_click_from(c) for c in cs] for cs in d.get("alternatives", [])]
            if any(len(cs) != len(clicks) for cs in alternatives):
                raise ValueError("a click set with another number of clicks than the first")
            return cls(int(d["view_index"]), str(d["view"]), float(d["time"]), clicks, str(d.get("source", "")),
                       alternatives)
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, PromptError):
                raise
            raise PromptError(f"{path}: malformed prompts file ({type(exc).__name__}: {exc})") from None

    def frames(self) -> list[int]:
        """The test frames the clicks were made in, in order."""
        return sorted({c.view_index for c in self.clicks})

    def click_sets(self) -> list[BenchmarkPrompts]:
        """Set 0 (these clicks) then each alternative set, as prompts of their own."""
        return [self] + [dataclasses.replace(self, clicks=list(cs), alternatives=[]) for cs in self.alternatives]


def click_dict(c: Click) -> dict:
    """A click as the prompts file holds it; ``"positive": false`` only on a negative click, so
    files of positive clicks are as before polarity existed."""
    return {"u": c.u, "v": c.v, "view": c.view, "view_index": c.view_index, "time": c.time,
            **({} if c.positive else {"positive": False})}


def _click_from(c: dict) -> Click:
    positive = c.get("positive", True)
    if not isinstance(positive, bool):
        raise TypeError(f"a click's positive is true or false, not {positive!r}")
    return Click(float(c["u"]), float(c["v"]), str(c["view"]), None if c["time"] is None else float(c["time"]),
                 int(c["view_index"]), positive)


TRACK_FRAMES = 3  # alternative clicks are spread over an object's first three frames


def _alternative_click(track: list[tuple[int, np.ndarray]], views: Sequence, j: int, k: int) -> Click:
    """Click set j's click on object k: frame (j-1) % TRACK_FRAMES of its track (the last when
    shorter), a pixel drawn from the region's interior half (seed (j, k))."""
    import cv2

    i, region = track[min((j - 1) % TRACK_FRAMES, len(track) - 1)]
    dist = cv2.distanceTransform(np.pad(region, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
    rows, cols = np.nonzero(dist >= 0.5 * dist.max())  # row-major order: deterministic
    pick = int(np.random.default_rng([j, k]).integers(len(rows)))
    view = views[i]
    return Click(float(cols[pick]) + 0.5, float(rows[pick]) + 0.5, view.name, float(view.camera.time), i)


def _follow(region: np.ndarray, gt: np.ndarray, kernel: np.ndarray) -> np.ndarray | None:
    """The connected region of ``gt`` overlapping (dilated) ``region`` most; None if none."""
    import cv2

    if gt.shape != region.shape or not gt.any():
        return None
    n, lab = cv2.connectedComponents(gt.astype(np.uint8), connectivity=8)
    near = cv2.dilate(region.astype(np.uint8), kernel) > 0
    counts = np.bincount(lab[near], minlength=n)
    counts[0] = 0
    return lab == int(np.argmax(counts)) if counts.max() > 0 else None


def make_benchmark_prompts(test_views: Sequence, gt_masks, min_area: int = 20,
                           rule: str = "gt-first-appearance", link_radius: int = 2,
                           click_sets: int = 1) -> BenchmarkPrompts:
    """Clicks from the test frames' ground truth by ``rule``, plus ``click_sets - 1``
    alternative click sets (module docstring)."""
    import cv2

    if rule not in BENCHMARK_RULES:
        raise PromptError(f"unknown benchmark prompt rule {rule!r}; choose one of {', '.join(BENCHMARK_RULES)}")
    if click_sets < 1:
        raise PromptError(f"click_sets={click_sets}: at least 1 (the clicks themselves)")
    kernel = np.ones((2 * link_radius + 1, 2 * link_radius + 1), np.uint8)
    clicks: list[Click] = []
    tracks: list[list[tuple[int, np.ndarray]]] = []  # per click: (frame, region) over its first frames
    first, seen = None, None  # seen [H, W]: object in some earlier test frame
    done = False  # gt-first-frame: no more clicks, only the tracks go on
    for i, (view, gt) in enumerate(zip(test_views, gt_masks)):
        gt = np.asarray(gt, dtype=bool)
        growing = [t for t in tracks if len(t) < TRACK_FRAMES and t[-1][0] == i - 1]
        for t in growing if click_sets > 1 else []:
            nxt = _follow(t[-1][1], gt, kernel)
            if nxt is not None:
                t.append((i, nxt))
        if done and not any(len(t) < TRACK_FRAMES and t[-1][0] == i for t in tracks):
            break
        if done:
            continue
        if first is None:
            regions = mask_regions(gt, min_area)
            if regions:
                first = i
        elif rule == "gt-first-frame":
            done = True
            continue
        else:
            near = cv2.dilate(seen.astype(np.uint8), kernel) > 0 if seen.shape == gt.shape else None
            regions = [r for r in mask_regions(gt, min_area, keep_largest=False)
                       if near is None or not (r[3] & near).any()]
        clicks += [Click(u, v, view.name, float(view.camera.time), i) for _, u, v, _ in regions]
        tracks += [[(i, region)] for _, _, _, region in regions]
        if gt.any():
            seen = gt.copy() if seen is None or seen.shape != gt.shape else seen | gt
    if first is None:
        raise PromptError("every test frame's ground truth is empty: no object to prompt")
    alternatives = [[_alternative_click(t, test_views, j, k) for k, t in enumerate(tracks)]
                    for j in range(1, click_sets)]
    v0 = test_views[first]
    return BenchmarkPrompts(first, v0.name, float(v0.camera.time), clicks, rule, alternatives)


def load_or_make_prompts(path: str | Path, test_views: Sequence, load_gt, min_area: int = 20,
                         rule: str = "gt-first-appearance", click_sets: int = 1) -> BenchmarkPrompts:
    """Reuse ``path`` (prompts.json) when it exists, else derive and save it atomically.

    load_gt(i) -> bool [H, W] ground truth of test view i (read lazily, in order)."""
    path = Path(path)
    if path.is_file():
        try:
            d = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise PromptError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
        return BenchmarkPrompts.from_dict(d, str(path))

    class _Lazy:
        def __iter__(self):
            for i in range(len(test_views)):
                yield load_gt(i)

    bp = make_benchmark_prompts(test_views, _Lazy(), min_area, rule, click_sets=click_sets)
    atomic_write_text(path, json.dumps(bp.to_dict(), indent=1))
    return bp
