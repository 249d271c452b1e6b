"""The contract every feature-learning objective implements, and the pair statistics they share.

One training step samples pixels and masks of one view (``PixelSample``), renders the
gaussian features at those pixels (``features [Np, D]``, unnormalised, as the rasterizer or
the frozen-geometry fast path returns them) and asks an ``Objective`` for a loss.

Pixels that fall in no *sampled* mask are dropped from the pair terms (``PairStats.valid``).
The public code keeps them, and such a pixel becomes a negative anchor against every other
pixel (its own C is 0 while its C_F with itself is 1), pushing apart pixels that an unsampled
mask may well group together. They still count in the feature-norm regulariser.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import torch
import torch.nn.functional as F

from lazyspecs import Registry, subclass_of

TAU_POS = 0.75  # positive pairs with cosine below this are imperfect (public code)
TAU_NEG = 0.5  # negative pairs with cosine above this are imperfect (public code)
W_MAX = 10.0  # pixel-pair weights are rescaled to [1, W_MAX]
# how two pixels' masks make their correspondence C: "binary" (the paper's: 1 iff they share a
# sampled mask) or "jaccard" (shared masks over the masks covering either; trase.objectives.soft)
CORRESPONDENCES = ("binary", "jaccard")


class ObjectiveInputError(ValueError):
    """Inconsistent objective input (shapes, dtypes); the message says which tensor."""

    user_facing = True


@dataclasses.dataclass
class PixelSample:
    """Pixels and masks sampled from one training view for one step."""

    pixels: torch.Tensor  # [Np] int64 linear pixel ids (row * W + col) at mask resolution
    membership: torch.Tensor  # [Np, M] bool: pixel i lies in sampled mask m
    mask_area: torch.Tensor  # [M] float: pixel count of each sampled mask
    pixel_mean_area: torch.Tensor  # [Np] float: mean area of ALL masks covering pixel (0: none)
    alpha: torch.Tensor | None = None  # [Np] rendered alpha (silhouette-based objectives)
    view: int = -1  # index of the training view, for logging
    # [H*W, D] the features rendered at every pixel of the view (at mask resolution), when the
    # step rendered the whole image: the feature-norm regulariser then averages over it, as the
    # public code does; None: it averages over the sampled pixels
    image_features: torch.Tensor | None = None

    def __post_init__(self) -> None:
        n = self.pixels.shape[0]
        if self.pixels.ndim != 1:
            raise ObjectiveInputError(f"pixels must be [Np], got {tuple(self.pixels.shape)}")
        if self.membership.ndim != 2 or self.membership.shape[0] != n:
            raise ObjectiveInputError(
                f"membership must be [Np={n}, M], got {tuple(self.membership.shape)}"
            )
        if self.membership.dtype != torch.bool:
            raise ObjectiveInputError(f"membership must be bool, got {self.membership.dtype}")
        if self.mask_area.shape != (self.membership.shape[1],):
            raise ObjectiveInputError(
                f"mask_area must be [M={self.membership.shape[1]}], got {tuple(self.mask_area.shape)}"
            )
        if self.pixel_mean_area.shape != (n,):
            raise ObjectiveInputError(
                f"pixel_mean_area must be [Np={n}], got {tuple(self.pixel_mean_area.shape)}"
            )
        if self.alpha is not None and self.alpha.shape != (n,):
            raise ObjectiveInputError(f"alpha must be [Np={n}], got {tuple(self.alpha.shape)}")
        if self.image_features is not None and self.image_features.ndim != 2:
            raise ObjectiveInputError(f"image_features must be [H*W, D], got {tuple(self.image_features.shape)}")

    @property
    def n_pixels(self) -> int:
        return int(self.pixels.shape[0])

    def to(self, device: torch.device | str) -> PixelSample:
        """This sample with every tensor on ``device`` (itself when they are there already)."""
        if self.pixels.device == torch.device(device):
            return self
        move = lambda t: None if t is None else t.to(device)
        return dataclasses.replace(
            self, pixels=move(self.pixels), membership=move(self.membership), mask_area=move(self.mask_area),
            pixel_mean_area=move(self.pixel_mean_area), alpha=move(self.alpha),
            image_features=move(self.image_features))

    @property
    def n_masks(self) -> int:
        return int(self.membership.shape[1])


@dataclasses.dataclass
class PairStats:
    """Pairwise quantities over the valid sampled pixels (those in >= 1 sampled mask)."""

    valid: torch.Tensor  # [Np] bool: pixel is in at least one sampled mask
    C: torch.Tensor  # [V, V] bool: valid pixels i, j share a sampled mask
    CF: torch.Tensor  # [V, V] cosine similarity of the normalised features (a constant: detached)
    W: torch.Tensor  # [V, V] pair weights in [1, W_MAX]
    upper: torch.Tensor  # [V, V] bool: i < j (non-redundant pairs)
    fn: torch.Tensor  # [V, D] L2-normalised features of the valid pixels (differentiable)
    # [V, V] the soft correspondence (``mask_jaccard``) when the objective reads it; None: binary
    share: torch.Tensor | None = None

    @property
    def positive(self) -> torch.Tensor:
        """[V, V] bool: the pairs that count as positives (C = 1; soft: C > 0)."""
        return self.C if self.share is None else self.share > 0

    @property
    def negative(self) -> torch.Tensor:
        """[V, V] bool: the pairs that count as negatives (C = 0; soft: C < 1)."""
        return ~self.C if self.share is None else self.share < 1

    def pair_weights(self) -> tuple[torch.Tensor, torch.Tensor]:
        """([V, V] weight of each pair as a positive, as a negative): W, W (binary C) or
        W C, W (1 - C) (soft)."""
        if self.share is None:
            return self.W, self.W
        return self.W * self.share, self.W * (1.0 - self.share)

    def pair_sum(self, coef: torch.Tensor) -> torch.Tensor:
        """sum_ij coef_ij C_F[i, j] for a constant coef [V, V], differentiable w.r.t. features.

        Equals ``(coef * (fn @ fn.T)).sum()`` but is computed as ``((coef @ fn) * fn).sum()``:
        autograd then records one [V, V] x [V, D] matmul instead of element-wise ops on
        [V, V] matrices, which is what made each training step slow at Np = 5000."""
        return ((coef.to(self.fn.dtype) @ self.fn) * self.fn).sum()


def check_features(features: torch.Tensor, sample: PixelSample) -> None:
    if features.ndim != 2 or features.shape[0] != sample.n_pixels:
        raise ObjectiveInputError(
            f"features must be [Np={sample.n_pixels}, D], got {tuple(features.shape)}"
        )
    if not features.is_floating_point():
        raise ObjectiveInputError(f"features must be floating point, got {features.dtype}")


def pair_weights(mean_area: torch.Tensor) -> torch.Tensor:
    """[V] mean covering-mask area per pixel -> [V, V] weights in [1, W_MAX].

    S = s s^T; W = max(S) / S clamped to >= 1 (S = 0 counts as huge, i.e. W = 1); then
    min-max rescaled to [1, W_MAX]. Small-segment pairs get large weights, so small objects
    are not drowned by the many pairs a large segment produces (as SAGA weighs pixels).

    Computed in closed form, O(V) work plus one outer product (this runs every step on
    Np x Np pairs): with a_i = max(s) / s_i, max(S) / S_ij = a_i a_j >= 1 (no clamp needed),
    the minimum is 1 (the largest s with itself) and the maximum (max a)^2; pairs with a
    zero s are exactly 1. ``pair_weights_reference`` is the literal formula the tests compare.
    """
    s = mean_area.to(torch.float64).reshape(-1)
    V = s.shape[0]
    if V == 0:
        return torch.ones(0, 0, dtype=torch.float32, device=mean_area.device)
    pos = s > 0
    if not bool(pos.any()):
        return torch.ones(V, V, dtype=torch.float32, device=mean_area.device)
    smax = s.max()
    a = torch.where(pos, smax / torch.where(pos, s, torch.ones_like(s)), torch.ones_like(s))  # [V] >= 1
    hi = float(a[pos].max()) ** 2
    if not hi > 1.0:
        return torch.ones(V, V, dtype=torch.float32, device=mean_area.device)
    af = a.to(torch.float32)
    W = torch.outer(af, af)  # [V, V] = max(S) / S where S > 0
    W.sub_(1.0).mul_((W_MAX - 1.0) / (hi - 1.0)).add_(1.0)
    zero = ~pos
    if bool(zero.any()):
        W[zero, :] = 1.0
        W[:, zero] = 1.0
    return W


def pair_weights_reference(mean_area: torch.Tensor) -> torch.Tensor:
    """The literal (slow, O(V^2) float64) form of ``pair_weights``, for tests."""
    s = mean_area.to(torch.float64)
    S = s[:, None] * s[None, :]
    smax = S.max() if S.numel() else S.new_tensor(0.0)
    W = torch.where(S > 0, smax / torch.where(S > 0, S, torch.ones_like(S)), torch.ones_like(S))
    W = W.clamp_min(1.0)
    if W.numel() == 0:
        return W.to(torch.float32)
    lo, hi = W.min(), W.max()
    if hi - lo > 0:
        W = 1.0 + (W_MAX - 1.0) * (W - lo) / (hi - lo)
    else:
        W = torch.ones_like(W)
    return W.to(torch.float32)


def mask_jaccard(member: torch.Tensor) -> torch.Tensor:
    """[V, M] bool membership of pixels in >= 1 mask -> [V, V] float32: shared masks over the
    masks covering either pixel (the soft correspondence; 1 on the diagonal)."""
    m = member.to(torch.float32)
    return _jaccard(m @ m.T, m.sum(dim=1))


def _jaccard(shared: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    """shared [V, V] mask counts (exact in float32 for M < 2^24), count [V] >= 1 -> [V, V]."""
    return shared / (count[:, None] + count[None, :] - shared)


def pair_stats(features: torch.Tensor, sample: PixelSample, correspondence: str = "binary") -> PairStats:
    """Correspondence C (and the soft one where asked), feature cosine C_F and weights W over
    the valid sampled pixels."""
    check_features(features, sample)
    if correspondence not in CORRESPONDENCES:
        raise ValueError(f"correspondence must be one of {CORRESPONDENCES}, got {correspondence!r}")
    member = sample.membership
    valid = member.any(dim=1)  # [Np]
    m = member[valid].to(torch.float32)  # [V, M]
    shared = m @ m.T  # [V, V] sampled masks both pixels lie in
    C = shared > 0
    f = F.normalize(features[valid], dim=1, eps=1e-12)  # zero features stay zero, not NaN
    with torch.no_grad():
        CF = f @ f.T  # [V, V]
    W = pair_weights(sample.pixel_mean_area[valid]).to(features.dtype)
    V = int(valid.sum())
    upper = torch.ones(V, V, dtype=torch.bool, device=features.device).triu(diagonal=1)
    share = _jaccard(shared, m.sum(dim=1)).to(features.dtype) if correspondence == "jaccard" else None
    return PairStats(valid=valid, C=C, CF=CF, W=W, upper=upper, fn=f, share=share)


def norm_regulariser(features: torch.Tensor) -> torch.Tensor:
    """(1 - mean ||F(p)||)^2 over the rows of ``features`` [P, D]: keeps rendered features near
    unit norm. Which pixels: ``regulariser_features``."""
    if features.shape[0] == 0:
        return features.sum() * 0.0
    return (1.0 - features.norm(dim=1).mean()) ** 2


def regulariser_features(features: torch.Tensor, sample: PixelSample) -> torch.Tensor:
    """The rendered features the norm regulariser averages over: the whole view when the step
    rendered it (``sample.image_features``; the public code's rule), else the sampled pixels
    ``features`` [Np, D] (the ``sampled`` setting of ``FeatureConfig.norm_reg_pixels``)."""
    return sample.image_features if sample.image_features is not None else features


class Objective(torch.nn.Module):
    """A feature-learning loss. Subclasses implement ``forward``; ``gaussian_loss`` is an
    optional extra term on the gaussians themselves (e.g. CGC's 3D spatial term)."""

    name: str = ""
    # True when the loss has the feature-norm regulariser: the trainer then renders the whole
    # view for it (``PixelSample.image_features``) if the config asks for the public rule
    uses_norm_regulariser: bool = False

    def forward(self, features: torch.Tensor, sample: PixelSample) -> tuple[torch.Tensor, dict]:
        """features [Np, D] rendered at sample.pixels -> (scalar loss, stats of floats)."""
        raise NotImplementedError

    def gaussian_loss(
        self, features: torch.Tensor, xyz: torch.Tensor, rng: torch.Generator | None = None
    ) -> torch.Tensor | None:
        """features [N, D], canonical positions [N, 3] -> scalar loss, or None (no 3D term)."""
        return None


# TRASE's own objective is declared here; other packages add theirs (``baselines`` registers
# its objectives when imported: the library knows none of them), installed packages through
# the entry-point group ``trase_bench.objectives`` (``name = module:ObjectiveSubclass``).
OBJECTIVES = Registry("objective", ObjectiveInputError, group="trase_bench.objectives",
                      check=subclass_of("trase.objectives.base:Objective"))
OBJECTIVES.add("trase", "trase.objectives.soft:SoftMining")


def register_objective(name: str) -> Callable:
    """Class decorator: make an objective constructible by name (``get_objective``)."""

    def wrap(cls):
        cls.name = name
        return OBJECTIVES.register(name)(cls)

    return wrap


def get_objective(name: str, **kwargs) -> Objective:
    """Build a registered objective (its module imported on first use); it carries the name
    it was asked by."""
    objective = OBJECTIVES.load(name)(**kwargs)
    objective.name = name
    return objective
