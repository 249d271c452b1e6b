"""Gaussians that do not move skip the deformation network.

Most of a dynamic scene (walls, floor, table) does not move, yet Deformable-3DGS evaluates its
network over every gaussian at every step, which is most of a CPU step. Here a trained
network's motion is measured per gaussian over the scene's times (``motion``: how far its
offsets move from their mean over time, in the scene's units); gaussians below a threshold
become static: their offsets are frozen at that mean, and ``PartlyStaticDeformation``
evaluates the network for the others only. Training re-measures at intervals, so a gaussian
whose network motion rises well above the threshold (``WAKE_FACTOR`` times it) is woken up
(``update_static``); it goes on from its frozen offsets, not from what the network, untrained
for it meanwhile, gives it: the difference is kept and added to the network's output.
Densified children inherit the flag with their parent's row (``trase.densify``'s row carry).

A frozen gaussian's network output is no longer trained, so a motion the network has not yet
learned when the gaussians are measured (an object crossing the scene in a few frames, learned
late) is frozen out for good. The training views show it: the views of the times it happens are
far worse than the others. So nothing new freezes while the worst of the measured times' views
lies more than ``time_gap`` dB below their median (``time_gap``; waking goes on), or, with a hold
region, nothing new freezes among the gaussians that draw those times' badly rendered pixels
(``lagging_times``; the trainer finds the gaussians), the rest of the scene freezing as usual.

Shapes: ``static`` [N] bool, ``frozen`` [N, 10] = d_xyz 3 | d_rot 4 | d_scale 3: a static
row's offsets; a moving row's correction added to the network's (zero unless it was woken).
"""

from __future__ import annotations

import math
import statistics

import torch
from torch import nn

FROZEN_WIDTH = 10  # d_xyz 3, d_rot 4, d_scale 3
WAKE_FACTOR = 2.0  # a static gaussian wakes when its motion exceeds this x the threshold (no flicker at it)


def split_offsets(frozen: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """[N, 10] -> d_xyz [N, 3], d_rot [N, 4], d_scale [N, 3]."""
    return frozen[:, :3], frozen[:, 3:7], frozen[:, 7:]


class PartlyStaticDeformation(nn.Module):
    """A deformation whose static rows keep frozen offsets; the network runs on the others.
    Row-aligned with its gaussians (``rows`` subsets it, as edits and the visible-only
    training pass do); the network itself is shared, not copied."""

    def __init__(self, net: nn.Module, static: torch.Tensor, frozen: torch.Tensor) -> None:
        super().__init__()
        if static.dim() != 1 or frozen.shape != (static.shape[0], FROZEN_WIDTH):
            raise ValueError(f"static must be [N] and frozen [N, {FROZEN_WIDTH}], got {tuple(static.shape)} "
                             f"and {tuple(frozen.shape)}")
        self.net = net
        self.register_buffer("static", static.to(torch.bool))
        self.register_buffer("frozen", frozen.to(torch.float32))

    @property
    def scale_rule(self) -> str | None:
        return getattr(self.net, "scale_rule", None)

    @property
    def num_gaussians(self) -> int:
        return int(self.static.shape[0])

    def rows(self, mask) -> PartlyStaticDeformation:
        m = torch.as_tensor(mask, dtype=torch.bool, device=self.static.device)
        return PartlyStaticDeformation(self.net, self.static[m], self.frozen[m])

    def forward(self, xyz: torch.Tensor, t) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        if xyz.shape[0] != self.num_gaussians:
            raise ValueError(f"PartlyStaticDeformation holds {self.num_gaussians} gaussians, got xyz for "
                             f"{xyz.shape[0]}")
        frozen = self.frozen.to(device=xyz.device, dtype=xyz.dtype)
        moving = torch.nonzero(~self.static.to(xyz.device)).reshape(-1)  # [M]
        d_xyz, d_rot, d_scale = split_offsets(frozen)
        if moving.numel() == self.num_gaussians:  # nothing static now (woken rows keep a correction)
            return tuple(o + c for o, c in zip(self.net(xyz, t), (d_xyz, d_rot, d_scale)))
        if moving.numel() == 0:
            return d_xyz, d_rot, d_scale
        m_xyz, m_rot, m_scale = self.net(xyz[moving], t)  # [M, 3], [M, 4], [M, 3]
        c_xyz, c_rot, c_scale = split_offsets(frozen[moving])  # corrections of woken rows (else zero)
        return d_xyz.index_copy(0, moving, m_xyz + c_xyz), d_rot.index_copy(0, moving, m_rot + c_rot), \
            d_scale.index_copy(0, moving, m_scale + c_scale)


@torch.no_grad()
def offsets_over_time(net: nn.Module, xyz: torch.Tensor, times: list[float]) -> torch.Tensor:
    """The network's offsets of every gaussian at each time -> [T, N, 10]."""
    return torch.stack([torch.cat(net(xyz, float(t)), dim=1) for t in times])


@torch.no_grad()
def motion(net: nn.Module, xyz: torch.Tensor, scales: torch.Tensor, times: list[float],
           extent: float) -> tuple[torch.Tensor, torch.Tensor]:
    """How much each gaussian moves over ``times`` -> (motion [N], mean offsets [N, 10]).

    motion = the largest, over times, of three distances from the gaussian's mean offsets, each
    in the scene's units as a fraction of its extent: its centre's; its size's (the scale
    offset); and how far turning moves its surface (the rotation offset, a fraction of a unit
    quaternion, times its largest scale). A gaussian below a threshold t moves, grows and turns
    by less than t x extent: at the built-in scenes' 160 px width one pixel is about 0.012 of
    the extent. Relative changes of size would count the jitter of tiny gaussians that no
    image shows (measured: half of a trained scene's gaussians change size by over 60%)."""
    off = offsets_over_time(net, xyz, times)  # [T, N, 10]
    mean = off.mean(0)  # [N, 10]
    dev = off - mean[None]
    size = scales.detach().amax(dim=1)  # [N]
    pos = dev[..., :3].norm(dim=-1).amax(0)
    turn = dev[..., 3:7].norm(dim=-1).amax(0) * size
    grow = dev[..., 7:].norm(dim=-1).amax(0)
    return torch.maximum(torch.maximum(pos, turn), grow) / max(float(extent), 1e-12), mean


@torch.no_grad()
def update_static(net: nn.Module, xyz: torch.Tensor, scales: torch.Tensor, times: list[float], extent: float,
                  threshold: float, static: torch.Tensor, frozen: torch.Tensor,
                  freeze: bool | torch.Tensor = True) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Re-measure every gaussian: moving ones below ``threshold`` become static with their mean
    offsets (the network's plus their correction) frozen; static ones whose network motion rose
    above WAKE_FACTOR x ``threshold`` wake up, the network driving them again from their frozen
    offsets (their correction: frozen - the network's mean). A static gaussian that stays static
    keeps its frozen offsets (the network's output for it is no longer trained, so only its
    motion over time is read). ``freeze`` False: only waking (a motion not learned yet: see
    ``time_gap``); or a bool [N]: only the rows where True may freeze (the others are held
    back). -> (static [N], frozen [N, 10], counts)."""
    mv, mean = motion(net, xyz, scales, times, extent)
    mean = mean.to(frozen.dtype)
    newly = ~static & (mv < threshold) & freeze
    woken = static & (mv > WAKE_FACTOR * threshold)
    frozen = torch.where(newly[:, None], mean + frozen, torch.where(woken[:, None], frozen - mean, frozen))
    static = (static & ~woken) | newly
    return static, frozen, {"static": int(static.sum()), "newly": int(newly.sum()), "woken": int(woken.sum())}


def per_time_psnr(view_psnr: list[float], view_times: list[float]) -> dict[float, float]:
    """Each time's PSNR (dB) from the mean squared error of its views, keyed by the time rounded
    to 9 digits (the cameras of a multi-view rig at one time count as one time)."""
    by_time: dict[float, list[float]] = {}
    for p, t in zip(view_psnr, view_times):
        by_time.setdefault(round(float(t), 9), []).append(10.0 ** (-float(p) / 10.0))  # PSNR -> MSE
    return {t: -10.0 * math.log10(max(sum(m) / len(m), 1e-20)) for t, m in by_time.items()}


def time_gap(view_psnr: list[float], view_times: list[float]) -> float:
    """dB by which the worst time's training views fall below the median time's. Large where
    some times show a motion not learned yet."""
    per_time = per_time_psnr(view_psnr, view_times)
    if not per_time:
        return 0.0
    return float(statistics.median(per_time.values()) - min(per_time.values()))


def lagging_times(view_psnr: list[float], view_times: list[float], gap_db: float) -> set[float]:
    """The times (keyed as ``per_time_psnr`` keys them) whose views lie more than ``gap_db`` dB
    below the median time's: where a motion has not been learned yet. Not empty exactly when
    ``time_gap`` exceeds ``gap_db`` (the same subtraction)."""
    per_time = per_time_psnr(view_psnr, view_times)
    if not per_time:
        return set()
    median = statistics.median(per_time.values())
    return {t for t, p in per_time.items() if median - p > gap_db}


def check_times(view_times: list[float], n: int = 16) -> list[float]:
    """Up to ``n`` of the training views' distinct times, evenly spread (the measurement's)."""
    ts = sorted({round(float(t), 9) for t in view_times})
    if len(ts) <= n:
        return ts
    idx = torch.linspace(0, len(ts) - 1, n).round().long().tolist()
    return [ts[i] for i in sorted(set(idx))]


__all__ = ["FROZEN_WIDTH", "WAKE_FACTOR", "PartlyStaticDeformation", "check_times", "lagging_times", "motion",
           "offsets_over_time", "per_time_psnr", "split_offsets", "time_gap", "update_static"]
