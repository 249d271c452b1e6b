"""SAM-like masks from instance ground truth, with controllable noise (synthetic scenes).

Why: on the built-in synthetic scenes we know every object, so we can produce masks whose
imperfections are the ones SAM shows and dial them up or down: objects split into parts,
neighbours merged, boundaries off by a pixel or two, objects missed, and the same object
present both whole and in parts. Masks carry no identity: each image draws its own noise from
``seed`` and the image key, and the mask order is shuffled.

Per instance id (> 0) of the map, with the image's rng:
  1. with prob ``p_drop`` it gets no mask at all;
  2. with prob ``p_split`` it is cut into 2..``max_parts`` parts by straight cuts across a
     random direction (part masks are added); when split, the whole is still added except
     with prob ``p_parts_only`` (whole-plus-part granularity);
  3. otherwise (and when not ``parts_only``) the whole mask is added;
  4. with prob ``p_merge`` the union with one random touching neighbour is added;
then, if ``p_background`` fires, each connected component of the id-0 region is added.
Every mask's boundary is moved by a smooth random offset in [-jitter_px, jitter_px]
(thresholding the signed distance plus a smooth noise field). Masks below SAM's scaled
minimum area (``min_area_for``), empty or full-image masks are dropped. Score = IoU of the
noisy mask with its clean source region, plus N(0, score_noise), clipped to [0, 1].
``info`` records per mask its kind (whole / part / merge / background) and source ids.
"""

from __future__ import annotations

import dataclasses
import zlib

import numpy as np

from masks.generators.base import drop_degenerate, min_area_for
from masks.maskset import MaskError, MaskSet


@dataclasses.dataclass(frozen=True)
class SyntheticNoise:
    p_drop: float = 0.05
    p_split: float = 0.35
    max_parts: int = 3
    p_parts_only: float = 0.3
    p_merge: float = 0.15
    jitter_px: float = 1.0
    p_background: float = 0.7
    score_noise: float = 0.02
    min_area: int | None = None  # None: SAM's 100 px scaled to the image size

    def __post_init__(self) -> None:
        for f in ("p_drop", "p_split", "p_parts_only", "p_merge", "p_background"):
            v = getattr(self, f)
            if not 0.0 <= v <= 1.0:
                raise MaskError(f"synthetic noise: {f} must be a probability, got {v}")
        if self.max_parts < 2:
            raise MaskError(f"synthetic noise: max_parts must be >= 2, got {self.max_parts}")
        if self.jitter_px < 0 or self.score_noise < 0:
            raise MaskError("synthetic noise: jitter_px and score_noise must be >= 0")

    @classmethod
    def clean(cls) -> SyntheticNoise:
        """No noise at all: one exact mask per instance (plus background components)."""
        return cls(p_drop=0, p_split=0, p_parts_only=0, p_merge=0, jitter_px=0, score_noise=0)


def _smooth_field(rng: np.random.Generator, h: int, w: int, amp: float, cells: int = 6):
    """[H, W] float32 smooth noise in [-amp, amp] (bilinear upsampling of a coarse grid)."""
    import cv2

    coarse = rng.uniform(-amp, amp, (cells + 1, cells + 1)).astype(np.float32)
    return cv2.resize(coarse, (w, h), interpolation=cv2.INTER_LINEAR)


def _jitter(mask: np.ndarray, rng: np.random.Generator, amp: float) -> np.ndarray:
    """Move the boundary of ``mask`` by a smooth random offset of at most ``amp`` pixels."""
    if amp <= 0 or not mask.any():
        return mask.copy()
    import cv2

    h, w = mask.shape
    pad = int(np.ceil(amp)) + 2
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    r0, r1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, h)
    c0, c1 = max(cols[0] - pad, 0), min(cols[-1] + pad + 1, w)
    sub = mask[r0:r1, c0:c1].astype(np.uint8)
    inside = cv2.distanceTransform(sub, cv2.DIST_L2, 3)  # >0 inside: distance to outside
    outside = cv2.distanceTransform(1 - sub, cv2.DIST_L2, 3)
    sdf = np.where(sub > 0, inside - 0.5, 0.5 - outside)  # ~signed distance to the boundary
    field = _smooth_field(rng, r1 - r0, c1 - c0, amp)
    out = np.zeros_like(mask)
    out[r0:r1, c0:c1] = (sdf + field) > 0
    return out


def _split(mask: np.ndarray, n_parts: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Cut ``mask`` into ``n_parts`` pieces by parallel straight cuts across a random direction."""
    ys, xs = np.nonzero(mask)
    theta = rng.uniform(0, np.pi)
    proj = xs * np.cos(theta) + ys * np.sin(theta)
    qs = np.sort(rng.uniform(0.25, 0.75, n_parts - 1)) if n_parts > 2 else [rng.uniform(0.3, 0.7)]
    cuts = np.quantile(proj, qs)
    part_id = np.searchsorted(cuts, proj)
    parts = []
    for p in range(n_parts):
        m = np.zeros_like(mask)
        sel = part_id == p
        m[ys[sel], xs[sel]] = True
        parts.append(m)
    return parts


def _neighbours(ids: np.ndarray) -> dict[int, set[int]]:
    """Instance ids (> 0) that touch each other (4-connectivity)."""
    pairs = np.concatenate([
        np.stack([ids[:, :-1].ravel(), ids[:, 1:].ravel()], 1),
        np.stack([ids[:-1, :].ravel(), ids[1:, :].ravel()], 1),
    ])
    pairs = pairs[(pairs[:, 0] != pairs[:, 1]) & (pairs > 0).all(1)]
    out: dict[int, set[int]] = {}
    for a, b in np.unique(pairs, axis=0):
        out.setdefault(int(a), set()).add(int(b))
        out.setdefault(int(b), set()).add(int(a))
    return out


class SyntheticGenerator:
    """Noisy SAM-like masks from an instance-id map [H, W] (0 = no object)."""

    name = "synthetic"
    needs_instance_map = True

    def __init__(self, seed: int = 0, noise: SyntheticNoise | None = None, **noise_overrides):
        base = noise or SyntheticNoise()
        self.seed = int(seed)
        self.noise = dataclasses.replace(base, **noise_overrides) if noise_overrides else base

    def settings(self) -> dict:
        return {"seed": self.seed, **dataclasses.asdict(self.noise)}

    def rng_for(self, key: str) -> np.random.Generator:
        """The image's own rng: from the seed and the image key, never shared across images."""
        return np.random.default_rng([self.seed, zlib.crc32(key.encode("utf-8"))])

    def generate(self, image: np.ndarray | None = None, key: str = "",
                 instance_map: np.ndarray | None = None) -> MaskSet:
        if instance_map is None:
            raise MaskError(f"synthetic generator needs an instance map (image {key!r})")
        ids = np.asarray(instance_map)
        if ids.ndim != 2 or not np.issubdtype(ids.dtype, np.integer):
            raise MaskError(f"instance map of {key!r} must be a 2D integer array, got "
                            f"{ids.dtype} {ids.shape}")
        if ids.size and ids.min() < 0:
            raise MaskError(f"instance map of {key!r} has negative ids")
        ids = ids.astype(np.int64)
        h, w = ids.shape
        nz = self.noise
        rng = self.rng_for(key)
        min_area = nz.min_area if nz.min_area is not None else min_area_for(h, w)

        # (clean source mask, kind, source ids)
        sources: list[tuple[np.ndarray, str, list[int]]] = []
        present = [int(i) for i in np.unique(ids) if i > 0]
        neigh = _neighbours(ids) if nz.p_merge > 0 else {}
        for inst in present:
            whole = ids == inst
            if rng.random() < nz.p_drop:
                continue
            add_whole = True
            if rng.random() < nz.p_split and whole.sum() >= 2 * min_area:
                n_parts = int(rng.integers(2, nz.max_parts + 1))
                for part in _split(whole, n_parts, rng):
                    sources.append((part, "part", [inst]))
                add_whole = rng.random() >= nz.p_parts_only
            if add_whole:
                sources.append((whole, "whole", [inst]))
            if neigh.get(inst) and rng.random() < nz.p_merge:
                other = int(rng.choice(sorted(neigh[inst])))
                sources.append((whole | (ids == other), "merge", sorted([inst, other])))
        if rng.random() < nz.p_background and (ids == 0).any():
            import cv2

            n_cc, cc = cv2.connectedComponents((ids == 0).astype(np.uint8), connectivity=4)
            for c in range(1, n_cc):
                sources.append((cc == c, "background", [0]))

        noisy, scores, kinds, src_ids = [], [], [], []
        for clean, kind, sid in sources:
            m = _jitter(clean, rng, nz.jitter_px)
            inter = np.logical_and(m, clean).sum()
            union = np.logical_or(m, clean).sum()
            iou = inter / union if union else 0.0
            s = float(np.clip(iou + rng.normal(0, nz.score_noise) if nz.score_noise else iou, 0, 1))
            noisy.append(m)
            scores.append(s)
            kinds.append(kind)
            src_ids.append(sid)
        if not noisy:
            return MaskSet.empty(h, w, self.name, {"key": key, "settings": self.settings(),
                                                   "kinds": [], "source_ids": []})
        stack = np.stack(noisy)
        keep = np.flatnonzero(drop_degenerate(stack, min_area))
        keep = keep[rng.permutation(keep.shape[0])]  # no meaningful order, like SAM's
        info = {"key": key, "settings": self.settings(), "min_area": int(min_area),
                "kinds": [kinds[i] for i in keep], "source_ids": [src_ids[i] for i in keep]}
        return MaskSet.from_masks(stack[keep], score=np.asarray(scores, np.float32)[keep],
                                  generator=self.name, info=info)
