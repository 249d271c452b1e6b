"""Prompts: from a click or a 2D mask in a (novel) view to gaussian clusters.

* Click (paper, supplementary "Testing implementation details"): render depth at the click's
  camera and time, unproject the pixel with K^-1 and c2w, take the nearest *deformed*
  gaussian at that time (KD-tree), return its cluster. A click on a pixel with rendered alpha
  below ``min_alpha`` hits nothing (-1): there is no surface to lift it to. The "weight" rule
  instead takes the cluster rendered most under the cursor (a 3x3 window); see
  ``click_to_cluster``.
* 2D mask prompt (the public code's text-prompt path): every mask pixel with a rendered surface
  is lifted the same way; a cluster is chosen when at least ``min_share`` of the lifted pixels
  land on its gaussians.
* Benchmark prompts: deterministic clicks from the test frames' ground truth, one per connected
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
* Oracle selection: the clusters whose visible rendered pixels (cluster weight >= 0.5 in the
  full render) lie mostly (> ``min_inside``) inside the ground truth over all test frames:
  an upper bound on what clicking can achieve, reported separately, never as the score.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from trase.camera import Camera
from trase.deformation import deformed
from trase.io import atomic_write_text
from trase.render import pixel_weights, rasterize

PROMPTS_VERSION = 3  # 2: each click names its own test frame; 3: new objects linked to every earlier frame
CLICK_RULES = ("depth", "weight")
BENCHMARK_RULES = ("gt-first-appearance", "gt-first-frame")


class PromptError(ValueError):
    user_facing = True


@dataclasses.dataclass(frozen=True)
class Click:
    u: float  # pixel x (continuous; pixel centre of column c is c + 0.5)
    v: float  # pixel y
    view: str = ""  # name of the view the click was made in
    time: float | None = None  # None: the camera's time
    view_index: int = -1  # index of that view among the scene's test views (-1: unknown)


@torch.no_grad()
def geometry_at(gaussians, deformation, t: float):
    """(means, quats, scales, opacities) of the deformed gaussians at time t (detached)."""
    m, q, s = deformed(gaussians, deformation, t)
    return m.detach(), q.detach(), s.detach(), gaussians.opacities.detach()


@torch.no_grad()
def render_depth(gaussians, deformation, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """-> (depth [H, W], alpha [H, W]) of the full scene at camera.time."""
    m, q, s, o = geometry_at(gaussians, deformation, camera.time)
    if m.shape[0] == 0:
        z = np.zeros((camera.height, camera.width), np.float32)
        return z, z.copy()
    out = rasterize(m, q, s, o, camera, features=torch.zeros(m.shape[0], 1, dtype=m.dtype))
    return out.depth.cpu().numpy(), out.alpha.cpu().numpy()


def lift_pixels(
    gaussians, deformation, camera: Camera, uv: np.ndarray, min_alpha: float = 0.5,
    depth_alpha: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Pixels uv [P, 2] -> [P] int64 id of the nearest deformed gaussian to the unprojected
    surface point at camera.time; -1 where the rendered alpha is below min_alpha."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    out = np.full(uv.shape[0], -1, np.int64)
    if uv.shape[0] == 0 or gaussians.num_gaussians == 0:
        return out
    depth, alpha = depth_alpha if depth_alpha is not None else render_depth(gaussians, deformation, camera)
    H, W = depth.shape
    col = np.clip(np.floor(uv[:, 0]).astype(np.int64), 0, W - 1)
    row = np.clip(np.floor(uv[:, 1]).astype(np.int64), 0, H - 1)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    ok = inside & (alpha[row, col] >= min_alpha) & (depth[row, col] > 0)
    if not ok.any():
        return out
    pts = camera.unproject(uv[ok], depth[row[ok], col[ok]])
    means = geometry_at(gaussians, deformation, camera.time)[0].cpu().numpy().astype(np.float64)
    _, idx = cKDTree(means).query(pts, k=1)
    out[ok] = np.asarray(idx, dtype=np.int64)
    return out


def click_to_cluster(gaussians, deformation, camera: Camera, click: Click, labels: np.ndarray,
                     min_alpha: float = 0.5, rule: str = "depth", radius: int = 1) -> int:
    """One click -> cluster id (-1 when the click hits no surface).

    ``rule="depth"`` (the paper's): rendered depth -> 3D point -> nearest deformed gaussian.
    ``rule="weight"``: the cluster with the largest compositing weight in the
    (2 radius + 1)^2 window at the click, i.e. what is rendered under the cursor. Why: on
    semi-transparent reconstructed surfaces the rendered (expected) depth falls between the
    object and what lies behind it, and the nearest gaussian there can be the background's
    (synthetic Immersive, CPU geometry: a click with alpha 1.0, weights 0.76 object / 0.22
    background chose the background cluster: mIoU 0.10, oracle 0.77)."""
    if rule not in CLICK_RULES:
        raise PromptError(f"unknown click rule {rule!r}; choose one of {', '.join(CLICK_RULES)}")
    cam = camera if click.time is None else camera.with_time(click.time)
    if rule == "weight":
        return _cluster_under_cursor(gaussians, deformation, cam, click.u, click.v, labels, min_alpha, radius)
    gid = int(lift_pixels(gaussians, deformation, cam, np.array([[click.u, click.v]]), min_alpha)[0])
    return -1 if gid < 0 else int(labels[gid])


@torch.no_grad()
def _cluster_under_cursor(gaussians, deformation, camera: Camera, u: float, v: float, labels: np.ndarray,
                          min_alpha: float, radius: int) -> int:
    """The cluster with the largest summed compositing weight over the window of pixels
    around (u, v); -1 off the image, on an empty scene, or where the click pixel's alpha is
    below min_alpha. Ties: the lowest cluster id."""
    if radius < 0:
        raise PromptError(f"click window radius must be >= 0, got {radius}")
    W, H = camera.width, camera.height
    if not (0 <= u < W and 0 <= v < H) or gaussians.num_gaussians == 0:
        return -1
    col, row = int(np.floor(u)), int(np.floor(v))
    rows = np.arange(max(row - radius, 0), min(row + radius, H - 1) + 1)
    cols = np.arange(max(col - radius, 0), min(col + radius, W - 1) + 1)
    window = (rows[:, None] * W + cols[None, :]).reshape(-1)
    centre = int(np.flatnonzero(window == row * W + col)[0])
    m, q, s, o = geometry_at(gaussians, deformation, camera.time)
    pw = pixel_weights(m, q, s, o, camera, torch.from_numpy(window))
    indptr = pw.indptr.cpu().numpy()
    idx = pw.indices.cpu().numpy()
    w = pw.weights.cpu().numpy().astype(np.float64)
    if w[indptr[centre]:indptr[centre + 1]].sum() < min_alpha:
        return -1
    lab = np.asarray(labels, dtype=np.int64)[idx]
    ok = lab >= 0
    if not ok.any():
        return -1
    per_cluster = np.bincount(lab[ok], weights=w[ok])
    return int(np.argmax(per_cluster))


def mask_to_clusters(gaussians, deformation, camera: Camera, mask: np.ndarray, labels: np.ndarray,
                     min_share: float = 0.05, max_points: int = 4000, min_alpha: float = 0.5) -> list[int]:
    """2D mask [H, W] -> sorted cluster ids hit by >= min_share of the lifted mask pixels.

    At most ``max_points`` pixels are lifted (an evenly strided, deterministic subset)."""
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != (camera.height, camera.width):
        raise PromptError(f"mask prompt is {mask.shape[1]}x{mask.shape[0]} but the camera is "
                          f"{camera.width}x{camera.height}")
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        return []
    step = max(1, int(np.ceil(rows.size / max_points)))
    rows, cols = rows[::step], cols[::step]
    uv = np.stack([cols + 0.5, rows + 0.5], axis=1)
    gids = lift_pixels(gaussians, deformation, camera, uv, min_alpha)
    hit = gids[gids >= 0]
    if hit.size == 0:
        return []
    lab = np.asarray(labels)[hit]
    values, counts = np.unique(lab, return_counts=True)
    share = counts / hit.size
    return sorted(int(v) for v, s in zip(values, share) if s >= min_share)


# ---------------------------------------------------------------- benchmark prompts
def _regions(gt: np.ndarray, min_area: int, keep_largest: bool = True) -> list[tuple[int, float, float, np.ndarray]]:
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
    return [(u, v) for _, u, v, _ in _regions(gt, min_area)]


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
            "clicks": [_click_dict(c) for c in self.clicks],
            "alternatives": [[_click_dict(c) for c in clicks] for clicks in self.alternatives],
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


def _click_dict(c: Click) -> dict:
    return {"u": c.u, "v": c.v, "view": c.view, "view_index": c.view_index, "time": c.time}


def _click_from(c: dict) -> Click:
    return Click(float(c["u"]), float(c["v"]), str(c["view"]), None if c["time"] is None else float(c["time"]),
                 int(c["view_index"]))


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
            regions = _regions(gt, min_area)
            if regions:
                first = i
        elif rule == "gt-first-frame":
            done = True
            continue
        else:
            near = cv2.dilate(seen.astype(np.uint8), kernel) > 0 if seen.shape == gt.shape else None
            regions = [r for r in _regions(gt, min_area, keep_largest=False)
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


# ---------------------------------------------------------------- oracle
@torch.no_grad()
def cluster_visibility(gaussians, deformation, camera: Camera, labels: np.ndarray, n_clusters: int) -> np.ndarray:
    """[H, W, C] rendered weight of each cluster in the full scene (occlusion-aware)."""
    m, q, s, o = geometry_at(gaussians, deformation, camera.time)
    onehot = torch.nn.functional.one_hot(torch.as_tensor(labels, dtype=torch.long), n_clusters).to(m.dtype)
    return rasterize(m, q, s, o, camera, features=onehot).features.cpu().numpy()


def oracle_clusters(gaussians, deformation, cameras: Sequence[Camera], gts: Sequence[np.ndarray],
                    labels: np.ndarray, min_inside: float = 0.5) -> list[int]:
    """Clusters whose visible pixels (weight >= 0.5) are > min_inside inside the ground truth,
    pooled over the given frames."""
    labels = np.asarray(labels, dtype=np.int64)
    if labels.size == 0:
        return []
    C = int(labels.max()) + 1
    inside = np.zeros(C)
    total = np.zeros(C)
    for cam, gt in zip(cameras, gts):
        vis = cluster_visibility(gaussians, deformation, cam, labels, C) >= 0.5  # [H, W, C]
        g = np.asarray(gt, bool)[..., None]
        inside += (vis & g).sum(axis=(0, 1))
        total += vis.sum(axis=(0, 1))
    frac = np.divide(inside, total, out=np.zeros(C), where=total > 0)
    return [int(c) for c in range(C) if total[c] > 0 and frac[c] > min_inside]
