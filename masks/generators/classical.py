"""Offline "anything" masks without a network: graph-based segmentation at several scales.

Why: SAM needs a checkpoint and, realistically, a GPU; the benchmark must still run anywhere.
Felzenszwalb-Huttenlocher graph segmentation (``cv2.ximgproc.segmentation``) at a few values
of its scale ``k`` gives nested-ish partitions from parts to whole objects; pooled together they
are overlapping, multi-granularity masks like SAM's. Two more passes run on a strongly
blurred image (``blur_sigma``), which averages texture out so that whole textured objects
(bricks, checkerboards) can come out as one segment. Optionally SLIC superpixels add a
part-level layer.

Per candidate segment:
  * area = pixel count;
  * score = a stability-like number in [0, 1]: the mean, over the neighbouring scales of the
    same pass type, of the best IoU of this segment with any segment of that scale (a region that survives a change
    of scale is "stable", in the spirit of SAM's stability score);
Then, as SAM does: segments smaller than ``min_area`` (SAM's 100 px scaled to the image size,
``min_area_for``) and whole-image segments are dropped, and near-duplicates across scales are
removed greedily by score (mask IoU > ``dedup_iou``). ``k`` is scaled with the pixel count
(the FH threshold k/|C| is in pixels), so the same scene gives similar masks at any size.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from masks.generators.base import REFERENCE_PIXELS, check_image, min_area_for
from masks.maskset import MaskError, MaskSet


def _pair_iou(la: np.ndarray, lb: np.ndarray, area_a: np.ndarray, area_b: np.ndarray):
    """Sparse IoU between every segment of label map ``la`` and of ``lb`` (flat int arrays).

    Returns (a_idx, b_idx, iou) for the pairs that overlap.
    """
    nb = int(area_b.shape[0])
    joint = la.astype(np.int64) * nb + lb
    keys, inter = np.unique(joint, return_counts=True)
    a, b = keys // nb, keys % nb
    iou = inter / (area_a[a] + area_b[b] - inter)
    return a, b, iou


@dataclasses.dataclass
class ClassicalGenerator:
    scales: tuple[float, ...] = (150.0, 500.0, 1500.0, 5000.0)  # FH k at 536x960
    k_exponent: float = 0.3  # k scales with (pixels / 536*960) ** k_exponent (see docstring)
    sigma: float = 0.8  # Gaussian pre-smoothing of the FH segmentation
    blur_scales: tuple[float, ...] = (500.0, 1500.0)  # extra FH passes on a blurred image ...
    blur_sigma: float = 12.0  # ... with this sigma at 536x960 (scaled with the image's size):
    # averaging out texture (bricks, checkerboards) lets whole textured objects come out
    slic: bool = False  # add SLIC superpixels as a finest layer
    slic_region: int = 48  # SLIC region size in pixels at 536x960 (scaled by sqrt of size)
    dedup_iou: float = 0.9  # drop a mask whose IoU with a better-scored kept one exceeds this
    min_area: int | None = None  # None: SAM's 100 px scaled to the image size
    min_segment_px: int = 20  # FH merges smaller components into neighbours: an absolute floor
    # against pixel noise on small images, where the scaled min_area is only a few pixels
    max_masks: int = 512  # keep at most this many, the largest (textured images hit it)
    name: str = dataclasses.field(default="classical", init=False)
    needs_instance_map: bool = dataclasses.field(default=False, init=False)

    def __post_init__(self) -> None:
        if not self.scales or any(s <= 0 for s in self.scales):
            raise MaskError(f"classical generator: scales must be positive, got {self.scales}")
        if not 0 < self.dedup_iou <= 1:
            raise MaskError(f"classical generator: dedup_iou must be in (0, 1], got {self.dedup_iou}")

    def settings(self) -> dict:
        d = dataclasses.asdict(self)
        d["scales"] = list(self.scales)
        d["blur_scales"] = list(self.blur_scales)
        return d

    # ------------------------------------------------------------------ layers
    def _layers(self, img: np.ndarray, min_area: int) -> tuple[list[np.ndarray], list[int]]:
        """[H, W] int32 label maps (labels 0..L-1) and each one's group: 0 sharp FH scales,
        1 blurred FH scales, 2 SLIC. Stability compares a layer with its neighbours in its
        group (or with every other layer when it is alone in its group)."""
        import cv2

        h, w = img.shape[:2]
        ratio = h * w / REFERENCE_PIXELS
        min_size = int(max(min_area, self.min_segment_px))
        layers, groups = [], []
        passes = [(self.sigma, k, 0) for k in self.scales]
        blur = max(self.sigma, self.blur_sigma * np.sqrt(ratio))  # sigma is a length
        passes += [(blur, k, 1) for k in self.blur_scales]
        for sigma, k, group in passes:
            seg = cv2.ximgproc.segmentation.createGraphSegmentation(
                sigma=float(sigma), k=float(k) * ratio ** self.k_exponent, min_size=min_size)
            layers.append(seg.processImage(img).astype(np.int32))
            groups.append(group)
        if self.slic:
            region = max(4, round(self.slic_region * float(np.sqrt(ratio))))
            lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB)
            sp = cv2.ximgproc.createSuperpixelSLIC(lab, algorithm=cv2.ximgproc.SLICO,
                                                   region_size=region)
            sp.iterate(10)
            sp.enforceLabelConnectivity(max(1, min_area, self.min_segment_px))
            labels = sp.getLabels().astype(np.int32)
            _, labels = np.unique(labels, return_inverse=True)  # compact label ids
            layers.append(labels.reshape(h, w).astype(np.int32))
            groups.append(2)
        return layers, groups

    # ---------------------------------------------------------------- generate
    def generate(self, image: np.ndarray | None, key: str = "",
                 instance_map: np.ndarray | None = None) -> MaskSet:
        img = check_image(image, "classical generator")
        h, w = img.shape[:2]
        min_area = self.min_area if self.min_area is not None else min_area_for(h, w)
        maps, groups = self._layers(img, min_area)
        layers = [lm.reshape(-1) for lm in maps]  # [H*W] each
        areas = [np.bincount(lm).astype(np.int64) for lm in layers]  # [L_i] each
        pair = _PairIoU(layers, areas)
        best = _stability(groups, areas, pair)
        kept = self._dedup(_candidates(areas, best, min_area, h * w), pair, len(layers))
        if len(kept) > self.max_masks:
            # over the cap (textured images: one segment per brick or checker square): keep
            # the largest, so whole objects survive and texture tiles go first
            kept = sorted(kept, key=lambda t: -int(areas[t[0]][t[1]]))[: self.max_masks]

        masks = _rasterize_kept(kept, layers, areas, h, w)
        score = np.array([s for _, _, s in kept], np.float32)
        order = np.argsort(-masks.reshape(len(kept), h * w).sum(1), kind="stable")  # by area
        info = {"key": key, "min_area": int(min_area), "settings": self.settings()}
        return MaskSet.from_masks(masks[order], score=score[order], generator=self.name, info=info)

    def _dedup(self, cand: list[tuple], pair: _PairIoU, n_layers: int) -> list[tuple[int, int, float]]:
        """Greedy dedup across layers, best candidate first: a kept segment takes every segment
        of the other layers whose IoU with it exceeds ``dedup_iou`` (segments of one layer are
        disjoint, IoU 0) -> kept (layer, label, score)."""
        dup_partner: dict[tuple[int, int], dict[int, list]] = {}

        def partners(i, j):  # for each label of layer i: labels of layer j with IoU > dedup
            if (i, j) not in dup_partner:
                a, b, iou = pair(i, j)
                sel = iou > self.dedup_iou
                d: dict[int, list] = {}
                for x, y in zip(a[sel], b[sel]):
                    d.setdefault(int(x), []).append(int(y))
                dup_partner[(i, j)] = d
            return dup_partner[(i, j)]

        kept: list[tuple[int, int, float]] = []
        taken: set[tuple[int, int]] = set()
        for negscore, _, negi, lab in cand:
            i = -negi
            if (i, lab) in taken:
                continue
            kept.append((i, lab, -negscore))
            taken.add((i, lab))
            for j in range(n_layers):
                if j != i:
                    for other in partners(i, j).get(lab, ()):
                        taken.add((j, other))
        return kept


class _PairIoU:
    """``_pair_iou`` of two layers, computed once per ordered pair: stability and dedup both
    read it."""

    def __init__(self, layers: list[np.ndarray], areas: list[np.ndarray]) -> None:
        self.layers, self.areas = layers, areas
        self.cache: dict[tuple[int, int], tuple] = {}

    def __call__(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if (i, j) not in self.cache:
            self.cache[(i, j)] = _pair_iou(self.layers[i], self.layers[j], self.areas[i], self.areas[j])
        return self.cache[(i, j)]


def _stability(groups: list[int], areas: list[np.ndarray], pair: _PairIoU) -> dict[int, np.ndarray]:
    """Per layer i, per label: the mean best IoU with the neighbouring layers of the same group
    (every other layer when alone in its group; 1 when there is no other layer) -> {i: [L_i]}."""
    n_layers = len(areas)
    best = {}
    for i in range(n_layers):
        same = [j for j in range(n_layers) if groups[j] == groups[i]]
        pos = same.index(i)
        neigh = [same[q] for q in (pos - 1, pos + 1) if 0 <= q < len(same)]
        if not neigh:
            neigh = [j for j in range(n_layers) if j != i]
        acc = np.zeros(areas[i].shape[0])
        if not neigh:  # a single scale: nothing to compare with
            best[i] = np.ones_like(acc)
            continue
        for j in neigh:
            a, _, iou = pair(i, j)
            m = np.zeros_like(acc)
            np.maximum.at(m, a, iou)
            acc += m
        best[i] = acc / len(neigh)
    return best


def _candidates(areas: list[np.ndarray], best: dict[int, np.ndarray], min_area: int,
                n_pixels: int) -> list[tuple[float, int, int, int]]:
    """Segments neither too small nor the whole image, best score first (ties: larger area, then
    coarser layer), as sortable (-score, -area, -layer, label)."""
    cand = []
    for i, ar in enumerate(areas):
        ok = np.flatnonzero((ar >= min_area) & (ar < n_pixels))
        for lab in ok:
            cand.append((-float(best[i][lab]), -int(ar[lab]), -i, int(lab)))
    cand.sort()
    return cand


def _rasterize_kept(kept: list[tuple[int, int, float]], layers: list[np.ndarray], areas: list[np.ndarray],
                    h: int, w: int) -> np.ndarray:
    """The kept (layer, label) segments as [len(kept), H, W] bool masks, in ``kept`` order; one
    scatter per layer, not one pass per mask."""
    masks = np.zeros((len(kept), h * w), bool)
    for i in sorted({i for i, _, _ in kept}):
        row_of = np.full(areas[i].shape[0], -1, np.int64)
        for n, (j, lab, _) in enumerate(kept):
            if j == i:
                row_of[lab] = n
        rows = row_of[layers[i]]
        pix = np.flatnonzero(rows >= 0)
        masks[rows[pix], pix] = True
    return masks.reshape(len(kept), h, w)
