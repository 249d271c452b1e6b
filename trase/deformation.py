"""Time-dependent deformation of canonical gaussians: (xyz, t) -> (d_xyz, d_rot, d_scale).

Two implementations share one protocol:

* ``DeformMLP``: the Deformable-3DGS network (positional encoding of xyz and t, an MLP with a
  skip connection, three linear heads without activation). Its parameter names match the
  public code (``linear.{i}``, ``gaussian_warp``, ``gaussian_rotation``, ``gaussian_scaling``,
  and ``timenet.{0,2}`` in the D-NeRF "blender" variant) so ``deform/iteration_N/deform.pth``
  files written by Deformable-3DGS or TRASE load into it unchanged.
* ``TabulatedDeformation``: offsets given per time step and interpolated linearly; the
  synthetic scenes ship their ground-truth motion this way, so tests can skip training.

``deformed`` applies the offsets with Deformable-3DGS semantics: means + d_xyz,
normalize(q) + d_rot, exp(log_s) + d_scale.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import torch
import torch.nn.functional as F
from torch import nn

from trase import blas_linear
from trase.reconstruction_config import deform_shape

# Smallest scale handed to the rasterizer: exp(log_s) + d_scale may go negative.
MIN_SCALE = 1e-7
# How a scale plus its offset becomes the scale rendered (``offset_scales``)
SCALE_RULES = ("mirror", "clamp")


def offset_scales(scales: torch.Tensor, d_scale: torch.Tensor, rule: str = "mirror") -> torch.Tensor:
    """The rendered scales [N, 3] of exp(log_s) [N, 3] plus the network's d_scale [N, 3].

    ``mirror`` (the public code): |s + d|. The public code hands s + d to a rasterizer that uses
    only its square (the covariance R S S^T R^T), so a negative sum draws the gaussian at |s + d|
    and the gradient keeps acting on it. ``clamp`` (this project's first rule, which the cpu
    presets were tuned with): s + d floored at MIN_SCALE, under which a gaussian the network
    drives below zero vanishes at that time and gets no gradient to come back; on a GPU run of
    the paper preset the network parked 1% or more of the gaussians so (offsets of hundreds of
    units, scales at the floor) by iteration 5500 and the loss rose from 0.02 to 0.11
    (docs/notes/gpu.md). Both floor at MIN_SCALE."""
    s = scales + d_scale
    if rule == "mirror":
        s = s.abs()
    elif rule != "clamp":
        raise ValueError(f"scale rule must be one of {', '.join(SCALE_RULES)}, got {rule!r}")
    return torch.clamp(s, min=MIN_SCALE)


def scale_rule_of(deformation) -> str:
    """The scale rule a deformation was trained with (its ``scale_rule``; the public code's
    ``mirror`` for one that does not say, e.g. a table of final offsets, where both agree)."""
    return getattr(deformation, "scale_rule", None) or "mirror"


@runtime_checkable
class Deformation(Protocol):
    def __call__(self, xyz: torch.Tensor, t: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """xyz [N, 3] canonical means, t in [0, 1] -> (d_xyz [N, 3], d_rot [N, 4], d_scale [N, 3])."""
        ...


def positional_encoding(x: torch.Tensor, num_freqs: int) -> torch.Tensor:
    """NeRF encoding with the raw input first: [x, sin(x), cos(x), sin(2x), cos(2x), ...].

    x [..., d] -> [..., d * (1 + 2 * num_freqs)]; frequencies 2^0 .. 2^(num_freqs-1), the
    same order as Deformable-3DGS's embedder so trained weights stay meaningful.
    """
    if num_freqs == 0:
        return x
    freqs = 2.0 ** torch.arange(num_freqs, dtype=x.dtype, device=x.device)  # [F]
    xf = x[..., None, :] * freqs[:, None]  # [..., F, d]
    sc = torch.stack([torch.sin(xf), torch.cos(xf)], dim=-2)  # [..., F, 2, d]
    return torch.cat([x, sc.flatten(-3)], dim=-1)


class DeformMLP(nn.Module):
    """The Deformable-3DGS deformation network.

    depth D, width W, xyz encoded with ``xyz_freqs`` frequencies (10 in the paper), t with
    ``t_freqs`` (10 for real scenes; the D-NeRF "blender" variant uses 6 plus a small
    ``timenet`` that maps the time encoding to 30 channels). The encoded input is
    concatenated again after layer D // 2.
    """

    def __init__(
        self,
        D: int = 8,
        W: int = 256,
        xyz_freqs: int = 10,
        t_freqs: int | None = None,
        blender: bool = False,
        scale_rule: str = "mirror",
    ) -> None:
        super().__init__()
        if D < 2 or W < 1:
            raise ValueError(f"DeformMLP needs D >= 2 and W >= 1, got D={D}, W={W}")
        if scale_rule not in SCALE_RULES:
            raise ValueError(f"scale rule must be one of {', '.join(SCALE_RULES)}, got {scale_rule!r}")
        self.scale_rule = scale_rule  # how d_scale is applied (offset_scales); saved beside the weights
        self.D, self.W = D, W
        self.xyz_freqs = xyz_freqs
        self.t_freqs = t_freqs if t_freqs is not None else (6 if blender else 10)
        self.blender = blender
        self.skip = D // 2  # the encoded input is concatenated after this layer
        xyz_ch = 3 * (1 + 2 * xyz_freqs)
        t_ch = 1 * (1 + 2 * self.t_freqs)
        if blender:
            self.time_out = 30
            self.timenet = nn.Sequential(nn.Linear(t_ch, 256), nn.ReLU(inplace=True), nn.Linear(256, self.time_out))
            t_ch = self.time_out
        in_ch = xyz_ch + t_ch
        layers = [nn.Linear(in_ch, W)]
        for i in range(D - 1):
            layers.append(nn.Linear(W + in_ch, W) if i == self.skip else nn.Linear(W, W))
        self.linear = nn.ModuleList(layers)
        self.gaussian_warp = nn.Linear(W, 3)
        self.gaussian_rotation = nn.Linear(W, 4)
        self.gaussian_scaling = nn.Linear(W, 3)

    @torch.no_grad()
    def zero_heads(self) -> DeformMLP:
        """Zero the three output layers so the network starts as the identity deformation.

        The public code keeps PyTorch's default init, whose random offsets (~0.1-0.5 scene
        units) scramble the geometry when the deformation switches on after warm-up; it
        recovers over thousands of iterations, which a short CPU run cannot afford.
        """
        for head in (self.gaussian_warp, self.gaussian_rotation, self.gaussian_scaling):
            head.weight.zero_()
            head.bias.zero_()
        return self

    @classmethod
    def preset(cls, name: str, scale_rule: str = "mirror") -> DeformMLP:
        """A network by name: ``paper`` (D=8, W=256, Deformable-3DGS), ``small`` (D=4, W=64, for
        CPU training), or any depth and width written ``<D>x<W>`` (e.g. ``8x128``)."""
        D, W = deform_shape(name)
        return cls(D=D, W=W, scale_rule=scale_rule)

    def config(self) -> dict:
        """Constructor arguments, enough to rebuild the module before loading a state dict."""
        return {"D": self.D, "W": self.W, "xyz_freqs": self.xyz_freqs, "t_freqs": self.t_freqs, "blender": self.blender}

    def _times(self, xyz: torch.Tensor, t: float | torch.Tensor) -> torch.Tensor:
        """t as an [N, 1] tensor of xyz's dtype."""
        n = xyz.shape[0]
        if not torch.is_tensor(t):
            return torch.full((n, 1), float(t), dtype=xyz.dtype, device=xyz.device)
        if t.dim() == 0:
            return t.reshape(1, 1).expand(n, 1).to(xyz.dtype)
        if t.dim() == 1:
            return (t.reshape(-1, 1).expand(n, 1) if t.numel() == 1 else t.reshape(n, 1)).to(xyz.dtype)
        return t.to(xyz.dtype)

    def forward(self, xyz: torch.Tensor, t: float | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """xyz [N, 3]; t a float or [N, 1] tensor (per-gaussian times, e.g. with noise).

        With one time for all gaussians (a float, a 0-d or 1-element tensor: every training
        and rendering call) the time encoding is a single row, so the layers that read the
        encoded input are split by columns: W [x_emb, t_emb] + b = W_x x_emb + (W_t t_emb + b),
        the bracket computed once. That skips two [N, in] concatenations and 21 of the 84
        input columns of two layers; the result equals ``forward_reference`` up to rounding.
        """
        if torch.is_tensor(t) and t.numel() > 1:
            return self.forward_reference(xyz, t)
        t_val = float(t) if not torch.is_tensor(t) else float(t.reshape(-1)[0])
        t_emb = positional_encoding(torch.full((1, 1), t_val, dtype=xyz.dtype, device=xyz.device), self.t_freqs)
        if self.blender:
            t_emb = self.timenet(t_emb)  # [1, 30]
        x_emb = positional_encoding(xyz, self.xyz_freqs)  # [N, 3 (1 + 2F)]
        nx = x_emb.shape[1]

        def split_layer(layer: nn.Linear, h: torch.Tensor | None) -> torch.Tensor:
            # layer input is [x_emb, t_emb] (layer 0) or [x_emb, t_emb, h] (after the skip):
            # relu((x_emb W_x^T [+ h W_h^T]) + row) -> [N, W]
            w = layer.weight
            row = F.linear(t_emb, w[:, nx:nx + t_emb.shape[1]], layer.bias)  # [1, W]
            w_h = None if h is None else w[:, nx + t_emb.shape[1]:]
            return blas_linear.relu_sum(row, x_emb, w[:, :nx], h, w_h)

        h = None
        for i, layer in enumerate(self.linear):
            if i == 0 or i == self.skip + 1:
                h = split_layer(layer, h)
            else:
                h = blas_linear.relu_layer(layer, h)
        return tuple(blas_linear.layer(head, h) for head in (self.gaussian_warp, self.gaussian_rotation, self.gaussian_scaling))

    def forward_reference(self, xyz: torch.Tensor, t: float | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The network as the public code writes it (concatenated inputs); any t."""
        t = self._times(xyz, t)
        t_emb = positional_encoding(t, self.t_freqs)
        if self.blender:
            t_emb = self.timenet(t_emb)
        x_emb = positional_encoding(xyz, self.xyz_freqs)
        inp = torch.cat([x_emb, t_emb], dim=-1)
        h = inp
        for i, layer in enumerate(self.linear):
            h = F.relu(layer(h))
            if i == self.skip:
                h = torch.cat([inp, h], dim=-1)
        return self.gaussian_warp(h), self.gaussian_rotation(h), self.gaussian_scaling(h)


def infer_mlp_config(state_dict: dict) -> dict:
    """Rebuild DeformMLP constructor arguments from a Deformable-3DGS state dict.

    D from the number of ``linear.i`` layers, W from the first layer's output size, the
    time encoding size from the input width (xyz uses 10 frequencies in all public code).
    Raises ValueError when the dict does not look like that network.
    """
    idx = sorted({int(k.split(".")[1]) for k in state_dict if k.startswith("linear.") and k.endswith(".weight")})
    needed = ["gaussian_warp.weight", "gaussian_rotation.weight", "gaussian_scaling.weight"]
    missing = [k for k in needed if k not in state_dict]
    if not idx or missing:
        what = "no linear.N layers" if not idx else f"missing {', '.join(missing)}"
        raise ValueError(f"not a Deformable-3DGS deform network state dict ({what})")
    D = len(idx)
    first = state_dict["linear.0.weight"]
    W = int(first.shape[0])
    in_ch = int(first.shape[1])
    xyz_freqs = 10
    xyz_ch = 3 * (1 + 2 * xyz_freqs)
    blender = "timenet.0.weight" in state_dict
    if blender:
        t_ch = int(state_dict["timenet.0.weight"].shape[1])
    else:
        t_ch = in_ch - xyz_ch
    if t_ch < 1 or (t_ch - 1) % 2:
        raise ValueError(f"not a Deformable-3DGS deform network state dict (input width {in_ch})")
    return {"D": D, "W": W, "xyz_freqs": xyz_freqs, "t_freqs": (t_ch - 1) // 2, "blender": blender}


class TabulatedDeformation(nn.Module):
    """Offsets known at times[T], linearly interpolated between them (clamped outside).

    times [T] ascending, d_xyz [T, N, 3], d_rot [T, N, 4], d_scale [T, N, 3]; exact at the
    tabulated times. Holds buffers, not parameters: it describes given motion.
    """

    def __init__(self, times, d_xyz, d_rot, d_scale) -> None:
        super().__init__()
        times = torch.as_tensor(times, dtype=torch.float64).reshape(-1)
        d_xyz = torch.as_tensor(d_xyz, dtype=torch.float32)
        d_rot = torch.as_tensor(d_rot, dtype=torch.float32)
        d_scale = torch.as_tensor(d_scale, dtype=torch.float32)
        T = times.shape[0]
        if T < 1:
            raise ValueError("TabulatedDeformation needs at least one time")
        if d_xyz.dim() != 3 or d_xyz.shape[0] != T or d_xyz.shape[2] != 3:
            raise ValueError(f"d_xyz must be [T={T}, N, 3], got {tuple(d_xyz.shape)}")
        n = d_xyz.shape[1]
        if tuple(d_rot.shape) != (T, n, 4) or tuple(d_scale.shape) != (T, n, 3):
            raise ValueError(
                f"d_rot must be [{T}, {n}, 4] and d_scale [{T}, {n}, 3], got {tuple(d_rot.shape)}, {tuple(d_scale.shape)}"
            )
        if not bool(torch.isfinite(times).all()) or (T > 1 and not bool((times[1:] > times[:-1]).all())):
            raise ValueError("TabulatedDeformation times must be finite and strictly increasing")
        self.register_buffer("times", times)
        self.register_buffer("d_xyz", d_xyz)
        self.register_buffer("d_rot", d_rot)
        self.register_buffer("d_scale", d_scale)

    @property
    def num_gaussians(self) -> int:
        return int(self.d_xyz.shape[1])

    def rows(self, mask) -> TabulatedDeformation:
        """The table of the gaussians where mask [N] bool is True (edits that drop gaussians)."""
        m = torch.as_tensor(mask, dtype=torch.bool)
        return TabulatedDeformation(self.times, self.d_xyz[:, m], self.d_rot[:, m], self.d_scale[:, m])

    def _bracket(self, t: float) -> tuple[int, int, float]:
        """Indices (i0, i1) and weight w of t: value = (1 - w) * v[i0] + w * v[i1]."""
        times = self.times
        T = times.shape[0]
        if T == 1 or t <= float(times[0]):
            return 0, 0, 0.0
        if t >= float(times[-1]):
            return T - 1, T - 1, 0.0
        i1 = int(torch.searchsorted(times, torch.tensor([t], dtype=torch.float64, device=times.device), right=False)[0])
        if float(times[i1]) == t:
            return i1, i1, 0.0
        i0 = i1 - 1
        w = (t - float(times[i0])) / (float(times[i1]) - float(times[i0]))
        return i0, i1, w

    def forward(self, xyz: torch.Tensor, t: float | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        if torch.is_tensor(t):
            t = float(t.reshape(-1)[0])
        if xyz.shape[0] != self.num_gaussians:
            raise ValueError(f"TabulatedDeformation holds {self.num_gaussians} gaussians, got xyz for {xyz.shape[0]}")
        i0, i1, w = self._bracket(float(t))
        out = []
        for table in (self.d_xyz, self.d_rot, self.d_scale):
            v = table[i0] if w == 0.0 else table[i0] * (1.0 - w) + table[i1] * w
            out.append(v.to(device=xyz.device, dtype=xyz.dtype))
        return out[0], out[1], out[2]


def deformation_rows(deformation, mask):
    """The deformation of the gaussians where ``mask`` [N] bool is True: per-row deformations
    (tables, partly static networks, edits' compositions) keep their rows; a network, which
    sees positions rather than indices, is shared unchanged."""
    rows = getattr(deformation, "rows", None)
    return deformation if rows is None else rows(torch.as_tensor(mask, dtype=torch.bool))


def deformed(gaussians, deformation, t: float, detach_xyz_input: bool = True):
    """Means [N, 3], quats [N, 4] wxyz, scales [N, 3] of ``gaussians`` at time t.

    Deformable-3DGS semantics: means + d_xyz, normalize(q) + d_rot, exp(log_s) + d_scale;
    the network sees the canonical means detached (as in the public trainer). The scales follow
    the deformation's scale rule (``offset_scales``: the public code's |s + d| unless it was
    trained with ``clamp``). With ``deformation=None`` the canonical geometry is returned.
    """
    means = gaussians.means
    quats = gaussians.rotations
    scales = gaussians.scales
    if deformation is None:
        return means, quats, scales
    xyz_in = means.detach() if detach_xyz_input else means
    d_xyz, d_rot, d_scale = deformation(xyz_in, t)
    return means + d_xyz, quats + d_rot, offset_scales(scales, d_scale, scale_rule_of(deformation))


def deformed_visible(gaussians, deformation, t: float, visible):
    """``deformed`` where only the ``visible`` gaussians' offsets carry gradients.

    ``visible``: a callable (means [N, 3], quats [N, 4], scales [N, 3], all detached) -> bool
    mask [N] of the gaussians that can reach the image (e.g. the projection's radii > 0).
    The network runs once without autograd over every gaussian, then again with autograd
    over the visible rows only, whose offsets replace the first ones. The returned tensors
    equal ``deformed``'s up to rounding (a matrix product may round a row differently in a
    smaller batch), and so do all gradients: an invisible gaussian adds nothing to the image,
    so its offsets' gradients are zero either way. Why: in training, the network's backward
    over every gaussian is most of a CPU step, and a camera sees a fraction of the scene.
    """
    means, quats, scales = gaussians.means, gaussians.rotations, gaussians.scales
    if deformation is None:
        return means, quats, scales
    xyz = means.detach()
    rule = scale_rule_of(deformation)
    with torch.no_grad():
        d_xyz, d_rot, d_scale = deformation(xyz, t)
        mask = visible(xyz + d_xyz, quats.detach() + d_rot, offset_scales(scales.detach(), d_scale, rule))
    mask = torch.as_tensor(mask, dtype=torch.bool).reshape(-1)
    idx = torch.nonzero(mask).reshape(-1)  # [V]
    if idx.numel() > 0 and torch.is_grad_enabled():
        rows = deformation_rows(deformation, mask)
        v_xyz, v_rot, v_scale = rows(xyz[idx], t)  # [V, 3], [V, 4], [V, 3]
        d_xyz = d_xyz.index_copy(0, idx, v_xyz)
        d_rot = d_rot.index_copy(0, idx, v_rot)
        d_scale = d_scale.index_copy(0, idx, v_scale)
    return means + d_xyz, quats + d_rot, offset_scales(scales, d_scale, rule)

