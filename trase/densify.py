"""3DGS's adaptive density control: the screen-space gradient statistic (two ways of getting
it, see ``ReconstructionConfig.densify_statistic``), the scene extent its thresholds scale
with, one densify-and-prune step, and ``DensifyStrategy``, which runs them beside the training
loop (gsplat's strategy layout: its own state, one call before and one after the backward)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, ClassVar

import numpy as np
import torch

from trase.camera import Camera
from trase.gaussians import GaussianModel
from trase.reconstruction_config import ReconstructionConfig

if TYPE_CHECKING:
    from trase.render.types import RenderOutput


def scene_extent(cameras: Iterable[Camera]) -> float:
    """3DGS's scene radius: 1.1 x the largest camera-centre distance from their mean."""
    centers = np.stack([c.center for c in cameras])
    diag = float(np.linalg.norm(centers - centers.mean(0), axis=1).max())
    return max(diag * 1.1, 1e-6) if diag > 0 else 1.0


def in_view(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, camera: Camera) -> torch.Tensor:
    """[N] bool: the gaussians the rasterizer does not cull for ``camera`` (radii > 0); the
    numba projection on CPU (same radii as the torch reference, ~10x faster)."""
    from trase.render.numba_projection import project_gaussians_numba
    from trase.render.projection import project_gaussians

    project = project_gaussians_numba if means.device.type == "cpu" else project_gaussians
    return project(means, quats, scales, camera).radii > 0


def screen_grad_norm(grad_means2d: torch.Tensor, camera: Camera) -> torch.Tensor:
    """|dL/d(mean2D)| in NDC units [N] (3DGS's densification statistic) from the gradient of
    the rendered pixel positions [N, 2]: NDC spans W / 2 pixels per unit in x, H / 2 in y."""
    g = grad_means2d.detach().double()
    n = torch.hypot(g[:, 0] * (0.5 * camera.width), g[:, 1] * (0.5 * camera.height))
    return torch.where(torch.isfinite(n), n, torch.zeros_like(n)).float()


def lstsq_screen_grad_norm(grad_means: torch.Tensor, means: torch.Tensor, camera: Camera) -> torch.Tensor:
    """|dL/d(mean2D)| in NDC units [N] from dL/d(mean3D) [N, 3], by least squares through the
    projection Jacobian J = [[a, 0, -a u], [0, b, -b v]] (a = fx/z, b = fy/z, u = x/z, v = y/z):
    g2 = (J J^T)^-1 J g3, in closed form (det = a^2 b^2 (1 + u^2 + v^2) never vanishes).
    Gaussians at or behind the camera plane get 0."""
    R = torch.as_tensor(camera.w2c[:3, :3], dtype=torch.float64, device=means.device)
    t = torch.as_tensor(camera.w2c[:3, 3], dtype=torch.float64, device=means.device)
    p = means.detach().double() @ R.T + t
    g = grad_means.double() @ R.T  # camera-space gradient
    z = p[:, 2]
    front = z > 1e-6
    zs = torch.where(front, z, torch.ones_like(z))
    u, v = p[:, 0] / zs, p[:, 1] / zs
    a, b = camera.fx / zs, camera.fy / zs
    gp = g[:, 0] - u * g[:, 2]  # (J g)_0 / a
    gq = g[:, 1] - v * g[:, 2]  # (J g)_1 / b
    den = 1.0 + u * u + v * v
    gu = ((1 + v * v) * gp - u * v * gq) / (a * den)  # pixels
    gv = ((1 + u * u) * gq - u * v * gp) / (b * den)
    n = torch.hypot(gu * (0.5 * camera.width), gv * (0.5 * camera.height))
    return torch.where(front & torch.isfinite(n), n, torch.zeros_like(n)).float()


@torch.no_grad()
def densify_and_prune(g: GaussianModel, opt, cfg: ReconstructionConfig, grad_accum, denom,
                       extent: float, prune_large: bool, gen: torch.Generator,
                       carry: dict[str, torch.Tensor] | None = None,
                       cap: int | None = None) -> dict[str, torch.Tensor] | None:
    """3DGS densify_and_prune: clone small / split large high-gradient gaussians, then drop
    transparent ones and, after the first opacity reset, ones larger than 0.1 x the scene
    extent. (3DGS also tests a screen-size limit, but its radii statistic has just been reset
    to zero by the densification, so that test never fires; it is left out here.)

    ``carry``: other per-gaussian tensors [N, ...] (e.g. static flags) that follow the rows:
    a clone or a split child gets its parent's row. Returns them renumbered like the model.
    ``cap``: the gaussian count not to densify past (None: ``cfg.max_gaussians``; 0: none)."""
    cap = cfg.max_gaussians if cap is None else cap
    grads = torch.where(denom > 0, grad_accum / denom.clamp_min(1), torch.zeros_like(grad_accum))
    big = g.scales.max(dim=1).values > cfg.percent_dense * extent
    cand = grads >= cfg.densify_grad_threshold
    if cap > 0:
        # each clone adds one, each split adds one net (2 new, 1 removed)
        room = max(cap - g.num_gaussians, 0)
        if int(cand.sum()) > room:
            order = torch.argsort(torch.where(cand, grads, torch.full_like(grads, -1.0)), descending=True)
            keep = torch.zeros_like(cand)
            keep[order[:room]] = True
            cand = cand & keep
    clone = cand & ~big
    split = cand & big
    n0 = g.num_gaussians
    g.clone_gaussians(clone, opt)
    split = torch.cat([split, torch.zeros(g.num_gaussians - n0, dtype=torch.bool, device=split.device)])
    n1 = g.num_gaussians
    g.split_gaussians(split, opt, n=2, generator=gen)
    prune = g.opacities < cfg.min_opacity
    if prune_large:
        prune |= g.scales.max(dim=1).values > 0.1 * extent
    if bool(prune.all()):
        prune[torch.argmax(g.opacities)] = False  # never delete every gaussian
    g.prune(~prune, opt)
    if carry is None:
        return None
    out = {}
    for name, t in carry.items():  # the same row operations, in the same order
        t = torch.cat([t, t[clone]])
        t = torch.cat([t, t[split].repeat((2,) + (1,) * (t.dim() - 1))])  # split_gaussians' n = 2 children
        keep = torch.ones(t.shape[0], dtype=torch.bool, device=t.device)
        keep[:n1][split] = False
        out[name] = t[keep][~prune]
    return out


@dataclasses.dataclass
class DensifyStrategy:
    """Densification, pruning and opacity resets on ``cfg``'s schedule, with the statistic's
    accumulators as state: kept out of the training loop so the loop reads as one step, and so
    the state a resumed run needs (``state_dict``) is owned by what uses it.

    Per iteration: ``step_pre_backward`` before ``loss.backward()`` (keeps the gradient the
    statistic reads), ``step_post_backward`` after it and before the optimizer step."""

    cfg: ReconstructionConfig  # schedule, thresholds and ``densify_statistic``
    extent: float  # scene radius the size thresholds scale with (``scene_extent``)
    grad_accum: torch.Tensor | None = None  # [N] float32: summed screen-gradient norms (NDC)
    denom: torch.Tensor | None = None  # [N] float32: steps each gaussian was counted in
    # iteration -> the gaussian cap there (a primitive schedule, trase.resolution_schedule);
    # None: cfg.max_gaussians throughout
    cap_at: Callable[[int], int] | None = None

    STATE_KEYS: ClassVar[tuple[str, ...]] = ("grad_accum", "denom")  # trainer-state file keys

    def initialize_state(self, n: int, device: torch.device | str) -> None:
        """Zero statistics for ``n`` gaussians (at the start, and after each densification,
        which renumbers the gaussians)."""
        self.grad_accum = torch.zeros(n, device=device)
        self.denom = torch.zeros(n, device=device)

    def state_dict(self) -> dict[str, torch.Tensor]:
        """The statistics on the CPU, under STATE_KEYS (the trainer state's keys)."""
        return {"grad_accum": self.grad_accum.cpu(), "denom": self.denom.cpu()}

    def load_state_dict(self, state: dict, num_gaussians: int, device: torch.device | str) -> None:
        """Continue the statistics of ``state`` (a trainer state holding STATE_KEYS); a
        ValueError when they are for another number of gaussians than the model's."""
        if state["grad_accum"].shape[0] != num_gaussians:
            raise ValueError(f"trainer state is for {state['grad_accum'].shape[0]} gaussians, "
                             f"the point cloud has {num_gaussians}")
        self.grad_accum, self.denom = state["grad_accum"].to(device), state["denom"].to(device)

    def screen_tensor(self, out: RenderOutput, means: torch.Tensor) -> torch.Tensor:
        """The tensor whose gradient the statistic reads: the render's screen positions
        [N, 2] ("means2d") or the deformed 3D means [N, 3] ("lstsq")."""
        return out.means2d if self.cfg.densify_statistic == "means2d" else means

    def step_pre_backward(self, out: RenderOutput, means: torch.Tensor) -> None:
        """Keep the statistic's gradient through the backward (a non-leaf's is dropped)."""
        screen = self.screen_tensor(out, means)
        if screen.requires_grad:
            screen.retain_grad()

    @torch.no_grad()
    def step_post_backward(self, step: int, gaussians: GaussianModel, optimizer, out: RenderOutput,
                           means: torch.Tensor, camera: Camera, generator: torch.Generator,
                           carry: dict[str, torch.Tensor] | None = None) -> dict[str, torch.Tensor] | None:
        """Accumulate this view's statistic; on the schedule densify and prune (through
        ``optimizer``, whose moments follow the gaussians) and reset the opacities.
        ``means`` [N, 3]: the deformed means the view was rendered with. ``carry``: other
        per-gaussian tensors, returned renumbered like the gaussians (``densify_and_prune``)."""
        cfg = self.cfg
        if step >= cfg.densify_until:
            return carry
        self._accumulate(gaussians, out, means, camera)
        if step > cfg.densify_from and step % cfg.densify_interval == 0:
            prune_large = step > cfg.opacity_reset_interval
            cap = self.cap_at(step) if self.cap_at is not None else None
            carry = densify_and_prune(gaussians, optimizer, cfg, self.grad_accum, self.denom, self.extent,
                                      prune_large, generator, carry, cap)
            self.initialize_state(gaussians.num_gaussians, self.grad_accum.device)
        if step % cfg.opacity_reset_interval == 0 or (cfg.white_background and step == cfg.densify_from):
            gaussians.reset_opacity(optimizer)
        return carry

    def _accumulate(self, gaussians: GaussianModel, out: RenderOutput, means: torch.Tensor,
                    camera: Camera) -> None:
        """Add the screen-gradient norm [N] of the gaussians in view; no gradient, no count."""
        grad = self.screen_tensor(out, means).grad  # [N, 2] or [N, 3], None without one
        if self.cfg.densify_statistic == "means2d":
            vis = out.radii.to(self.grad_accum.device) > 0  # the render's own projection (3DGS)
            gn = screen_grad_norm(grad, camera) if grad is not None else None
        else:
            # the visibility the cpu presets were tuned with: deformed means, canonical
            # rotations and scales (the render's radii changed the seed-0 HyperNeRF
            # geometry: ceiling 0.7482 -> 0.7494, and its click then chose a background
            # cluster, mIoU 0.740 -> 0.130)
            mt = means.detach()
            vis = in_view(mt, gaussians.rotations.detach(), gaussians.scales.detach(), camera)
            gn = lstsq_screen_grad_norm(grad, mt, camera) if grad is not None else None
        if gn is not None:
            # masked adds without a boolean index (which waits for the device to count it):
            # the same sums, x + 0 = x for the gaussians out of view
            vis = vis.to(self.grad_accum.device)
            self.grad_accum += torch.where(vis, gn.to(self.grad_accum.dtype), 0.0)
            self.denom += vis.to(self.denom.dtype)
