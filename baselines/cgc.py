"""Contrastive Gaussian Clustering (``cgc``; Silva et al. 2024) as an objective on sampled pixels.

Facts from the public code (MyrnaCCS/contrastive-gaussian-clustering and the TRASE authors'
dynamic port yunjinli/contrastive-gaussian-clustering); the code here is our own.

2D term, per training view, over a *label map* (one segment id per pixel):

    f_j   = F(p_j) / ||F(p_j)||                      rendered features, L2-normalised
    f_m   = mean_{j in m} f_j                         per-label mean (gradient flows through it)
    phi_m = clip(10 * sum_{j in m} ||f_j - f_m|| / (n_m log(n_m + 100)), 0.1, 1)   detached
    L_2d  = mean_j  -log softmax_m( f_j . f_m / phi_m )[label_j]

3D spatial term on the gaussians (``gaussian_loss``): sample ``sample_size`` = 1000 gaussians
(after a random cap of ``max_points`` = 300000), find for each its ``k_pull`` = 2 nearest and
``k_push`` = 5 farthest gaussians by canonical position, and

    L_3d = 0.05 * sigmoid(1 - mean cos(f_s, f_near)) + 0.15 * sigmoid(mean cos(f_s, f_far))

Choices and differences from the public code:

* Label map from overlapping SAM masks. CGC expects one id per pixel; SAM masks overlap (parts
  inside wholes). Each sampled pixel takes the **smallest sampled mask that covers it** (by
  full-resolution area ``mask_area``; ties: lowest mask index), so parts win over wholes, as
  when masks are painted largest first. Pixels in no sampled mask get no label.
* Small segments. The public code drops label regions of <= ``min_pixnum`` = 100 pixels at
  full resolution. We cannot measure a region's full-resolution area from a pixel sample, so
  a label is dropped when its *mask* area is <= ``min_mask_pixels`` (the mask is a superset of
  its region: this drops a subset of what the public rule drops). Its pixels are then ignored,
  not relabelled. Scale: 100 px is 100 / (H W) of an image; on the benchmarks' mask
  resolutions (e.g. NeRF-DS 2x, 480 x 270 = 129600 px) that is 0.08 % of the image, on a
  128 x 128 synthetic image it is 0.6 %, large enough to drop small synthetic objects. Use
  ``min_mask_pixels_for(height, width)`` to keep the relative size (13 px at 128 x 128).
* Normalisation of L_2d. The public code sums -log softmax over each label's pixels, averages
  the sums over labels and scales by ``contrastive_lambda`` = 1e-6, on full rendered images.
  With sampled pixels we take the plain mean over labelled pixels (weight ``weight_2d`` = 1),
  so the term does not depend on the pixel count. Its scale relative to L_3d therefore differs
  from the public code (there, with ~1e5 pixels per image and ~20 labels, the 2D term is
  ~1e-6 * 5e3 * 3 ~ 0.02 per step, the same order as L_3d); ``weight_2d`` sets the balance.
* Cadence. The public code applies L_2d every 50 (original: 5) and L_3d every 100 steps; here
  both are applied whenever the training loop calls them (every step in the shared pipeline).
* The public code's nearest neighbours include the sampled gaussian itself (distance 0), so
  "2 nearest" is the gaussian and its nearest other one; we keep that (its own cosine is a
  constant 1 for non-zero features and adds no gradient).
* No feature-norm regulariser (CGC has none: both terms see only directions).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from trase.objectives.base import (
    Objective,
    ObjectiveInputError,
    PixelSample,
    check_features,
    register_objective,
)

PHI_MIN, PHI_MAX = 0.1, 1.0  # temperature clip (public code)
PHI_SCALE = 10.0  # temperature = 10 * mean distance / log(n + 100)
MIN_MASK_PIXELS = 100  # public ``min_pixnum`` at full resolution
REFERENCE_PIXELS = 480 * 270  # NeRF-DS 2x mask resolution, where the public value was used


def min_mask_pixels_for(height: int, width: int, reference_pixels: int = REFERENCE_PIXELS) -> int:
    """The public 100-pixel threshold rescaled to an image of ``height x width`` pixels,
    keeping the same fraction of the image (at least 1 pixel)."""
    if height <= 0 or width <= 0:
        raise ObjectiveInputError(f"image size must be positive, got {height} x {width}")
    return max(1, round(MIN_MASK_PIXELS * height * width / reference_pixels))


def cgc_labels(
    membership: torch.Tensor, mask_area: torch.Tensor, min_mask_pixels: float = MIN_MASK_PIXELS
) -> torch.Tensor:
    """membership [Np, M] bool, mask_area [M] -> labels [Np] int64 (mask index, -1: none).

    Each pixel takes its smallest covering mask (ties: lowest index); labels of masks with
    area <= min_mask_pixels are then dropped (-1)."""
    n, m = membership.shape
    if m == 0 or n == 0:
        return torch.full((n,), -1, dtype=torch.long, device=membership.device)
    area = mask_area.to(torch.float64)
    # Sort masks by (area, index); the first covering mask in that order wins.
    order = torch.argsort(area, stable=True)  # [M]
    covered = membership[:, order]  # [Np, M] in area order
    first = covered.to(torch.uint8).argmax(dim=1)  # [Np] first True (0 if none)
    labels = order[first]
    labels = torch.where(covered.any(dim=1), labels, torch.full_like(labels, -1))
    keep = area > float(min_mask_pixels)  # [M]
    labels = torch.where(
        (labels >= 0) & keep[labels.clamp_min(0)], labels, torch.full_like(labels, -1)
    )
    return labels


def cgc_temperature(f: torch.Tensor, onehot: torch.Tensor, means: torch.Tensor) -> torch.Tensor:
    """Detached per-label temperature phi [L] from normalised features f [K, D], one-hot
    label matrix onehot [K, L] and label means [L, D]."""
    with torch.no_grad():
        n = onehot.sum(dim=0)  # [L], >= 1 for every present label
        dist = (f[:, None, :] - means[None, :, :]).norm(dim=2)  # [K, L]
        spread = (dist * onehot).sum(dim=0)  # [L]
        phi = PHI_SCALE * spread / (n * torch.log(n + 100.0))
        return phi.clamp(PHI_MIN, PHI_MAX)


def cgc_2d_loss(features: torch.Tensor, labels: torch.Tensor) -> tuple[torch.Tensor, dict]:
    """features [Np, D], labels [Np] int64 (-1: ignored) -> (mean -log softmax, stats)."""
    if labels.shape != features.shape[:1]:
        raise ObjectiveInputError(
            f"labels must be [Np={features.shape[0]}], got {tuple(labels.shape)}"
        )
    keep = labels >= 0
    if not bool(keep.any()):
        return features.sum() * 0.0, {"n_labels": 0, "n_labelled": 0, "phi_mean": float("nan")}
    present, lab = torch.unique(labels[keep], return_inverse=True)  # [L], [K] in 0..L-1
    f = F.normalize(features[keep], dim=1, eps=1e-9)  # [K, D]; zero features stay zero
    onehot = F.one_hot(lab, present.shape[0]).to(f.dtype)  # [K, L]
    n = onehot.sum(dim=0)  # [L]
    means = (onehot.T @ f) / n[:, None]  # [L, D]
    phi = cgc_temperature(f, onehot, means)  # [L]
    logits = (f @ means.T) / phi[None, :]  # [K, L]
    loss = F.cross_entropy(logits, lab)
    stats = {
        "n_labels": int(present.shape[0]),
        "n_labelled": int(keep.sum()),
        "phi_mean": float(phi.mean()),
    }
    return loss, stats


def nearest_farthest(
    sample_xyz: torch.Tensor, xyz: torch.Tensor, k_near: int, k_far: int, chunk: int = 64
) -> tuple[torch.Tensor, torch.Tensor]:
    """Indices [S, k_near] of the nearest and [S, k_far] of the farthest points of xyz [N, 3]
    for each of sample_xyz [S, 3]; chunked over S so memory stays O(chunk * N). Distances are
    computed directly (not via |a|^2 + |b|^2 - 2ab), so close neighbours rank exactly."""
    near, far = [], []
    with torch.no_grad():
        for s in range(0, sample_xyz.shape[0], chunk):
            d = torch.cdist(
                sample_xyz[s : s + chunk], xyz, compute_mode="donot_use_mm_for_euclid_dist"
            )  # [c, N]
            near.append(d.topk(k_near, dim=1, largest=False).indices)
            far.append(d.topk(k_far, dim=1, largest=True).indices)
    if not near:
        empty = torch.zeros(0, dtype=torch.long, device=xyz.device)
        return empty.reshape(0, k_near), empty.reshape(0, k_far)
    return torch.cat(near), torch.cat(far)


def _fingerprint(xyz: torch.Tensor) -> tuple:
    """Cheap O(N) identity of a point set (shape, device and two weighted sums)."""
    x = xyz.detach().to(torch.float64)
    w = torch.arange(1, x.shape[0] + 1, dtype=torch.float64, device=x.device)[:, None]
    return (tuple(x.shape), str(xyz.device), float(x.sum()), float((x * w).sum()))


class NeighbourTable:
    """Memoised nearest / farthest neighbour indices of a fixed point set.

    Geometry is frozen during feature learning, so a gaussian's neighbours never change: each
    is computed the first time the gaussian is sampled and reused after (the public code
    recomputes 1000 x N distances every call). Results equal ``nearest_farthest``."""

    def __init__(self, xyz: torch.Tensor, k_near: int, k_far: int) -> None:
        n = xyz.shape[0]
        self.xyz = xyz.detach()
        self.k_near, self.k_far = int(k_near), int(k_far)
        self.near = torch.zeros(n, self.k_near, dtype=torch.long, device=xyz.device)
        self.far = torch.zeros(n, self.k_far, dtype=torch.long, device=xyz.device)
        self.known = torch.zeros(n, dtype=torch.bool, device=xyz.device)
        self.fingerprint = _fingerprint(xyz)

    def matches(self, xyz: torch.Tensor, k_near: int, k_far: int) -> bool:
        return (self.k_near, self.k_far) == (k_near, k_far) and self.fingerprint == _fingerprint(
            xyz
        )

    def lookup(self, pick: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """pick [S] indices -> (near [S, k_near], far [S, k_far])."""
        missing = torch.unique(pick[~self.known[pick]])
        if missing.numel():
            near, far = nearest_farthest(self.xyz[missing], self.xyz, self.k_near, self.k_far)
            self.near[missing], self.far[missing] = near, far
            self.known[missing] = True
        return self.near[pick], self.far[pick]


def cgc_spatial_loss(
    features: torch.Tensor,
    xyz: torch.Tensor,
    rng: torch.Generator | None = None,
    k_pull: int = 2,
    k_push: int = 5,
    lambda_pull: float = 0.05,
    lambda_push: float = 0.15,
    sample_size: int = 1000,
    max_points: int = 300_000,
    table: NeighbourTable | None = None,
) -> torch.Tensor:
    """features [N, D] per gaussian, canonical xyz [N, 3] (not differentiated) -> scalar.

    L = lambda_pull * sigmoid(1 - mean cos(f_s, f_near))
        + lambda_push * sigmoid(mean cos(f_s, f_far)).
    k is capped at N; N = 0 gives a zero loss. ``table`` (for this xyz, used only when no
    random cap applies) memoises the neighbour search."""
    if (
        features.ndim != 2
        or xyz.ndim != 2
        or xyz.shape[1] != 3
        or xyz.shape[0] != features.shape[0]
    ):
        raise ObjectiveInputError(
            f"gaussian features must be [N, D] and xyz [N, 3] with the same N, got "
            f"{tuple(features.shape)} and {tuple(xyz.shape)}"
        )
    if not features.is_floating_point():
        raise ObjectiveInputError(f"gaussian features must be floating point, got {features.dtype}")
    n = features.shape[0]
    if n == 0:
        return features.sum() * 0.0
    xyz = xyz.detach().to(features.device)
    capped = n > max_points
    if capped:  # random cap, as the public code (on GPU it bounds the cdist)
        idx = torch.randperm(n, generator=rng)[:max_points].to(features.device)
        xyz, features = xyz[idx], features[idx]
        n = max_points
    pick = torch.randperm(n, generator=rng)[:sample_size].to(features.device)  # [S]
    kn, kf = min(k_pull, n), min(k_push, n)
    if table is not None and not capped:
        near, far = table.lookup(pick)
    else:
        near, far = nearest_farthest(xyz[pick], xyz, kn, kf)
    fs = features[pick]  # [S, D]
    cos_near = F.cosine_similarity(fs[:, None, :], features[near], dim=-1, eps=1e-10)  # [S, kn]
    cos_far = F.cosine_similarity(fs[:, None, :], features[far], dim=-1, eps=1e-10)  # [S, kf]
    pull = lambda_pull * torch.sigmoid(1.0 - cos_near.mean())
    return pull + lambda_push * torch.sigmoid(cos_far.mean())


def cgc_loss(
    features: torch.Tensor, sample: PixelSample, min_mask_pixels: float = MIN_MASK_PIXELS
) -> tuple[torch.Tensor, dict]:
    """features [Np, D] rendered at sample.pixels -> (L_2d, stats). See module doc."""
    check_features(features, sample)
    labels = cgc_labels(sample.membership, sample.mask_area, min_mask_pixels)
    return cgc_2d_loss(features, labels)


@register_objective("cgc")
class ContrastiveGaussianClustering(Objective):
    """CGC: per-label softmax contrast with adaptive temperature (2D) + 3D spatial term."""

    def __init__(
        self,
        min_mask_pixels: float = MIN_MASK_PIXELS,
        weight_2d: float = 1.0,
        weight_3d: float = 1.0,
        k_pull: int = 2,
        k_push: int = 5,
        lambda_pull: float = 0.05,
        lambda_push: float = 0.15,
        sample_size: int = 1000,
        max_points: int = 300_000,
    ) -> None:
        super().__init__()
        if min_mask_pixels < 0 or not math.isfinite(min_mask_pixels):
            raise ObjectiveInputError(f"min_mask_pixels must be >= 0, got {min_mask_pixels}")
        if k_pull < 1 or k_push < 1 or sample_size < 1 or max_points < 1:
            raise ObjectiveInputError(
                f"k_pull, k_push, sample_size, max_points must be >= 1, got "
                f"{k_pull}, {k_push}, {sample_size}, {max_points}"
            )
        self.min_mask_pixels = float(min_mask_pixels)
        self.weight_2d, self.weight_3d = float(weight_2d), float(weight_3d)
        self.k_pull, self.k_push = int(k_pull), int(k_push)
        self.lambda_pull, self.lambda_push = float(lambda_pull), float(lambda_push)
        self.sample_size, self.max_points = int(sample_size), int(max_points)
        self._table: NeighbourTable | None = None  # neighbours of the frozen gaussians

    def forward(self, features: torch.Tensor, sample: PixelSample) -> tuple[torch.Tensor, dict]:
        loss, stats = cgc_loss(features, sample, self.min_mask_pixels)
        stats["loss_2d"] = float(loss.detach())
        return self.weight_2d * loss, stats

    def gaussian_loss(
        self, features: torch.Tensor, xyz: torch.Tensor, rng: torch.Generator | None = None
    ) -> torch.Tensor | None:
        if self.weight_3d == 0.0:
            return None
        table = None
        n = xyz.shape[0] if xyz.ndim == 2 else 0
        if 0 < n <= self.max_points and xyz.shape[1] == 3 and features.shape[:1] == (n,):
            kn, kf = min(self.k_pull, n), min(self.k_push, n)
            if self._table is None or not self._table.matches(xyz, kn, kf):
                self._table = NeighbourTable(xyz.detach().to(features.device), kn, kf)
            table = self._table
        return self.weight_3d * cgc_spatial_loss(
            features,
            xyz,
            rng,
            self.k_pull,
            self.k_push,
            self.lambda_pull,
            self.lambda_push,
            self.sample_size,
            self.max_points,
            table,
        )
