"""The static checks of a reconstruction (the ``static_*`` settings): on their schedule, which
gaussians move is measured again, the still ones skip the deformation network from the next
step and the ones that move again are woken up; each check is logged in ``static_checks.csv``.
The measures of motion and the frozen rows: ``trase.static_gaussians``.
"""

from __future__ import annotations

from pathlib import Path

import torch

from trase.losses import psnr
from trase.reconstruction_config import ReconstructionConfig
from trase.render_views import render_view
from trase.trainer import Trainer
from trase.training_images import ImageCache

STATIC_CHECKS_FILE = "static_checks.csv"  # a row per check: see STATIC_CHECKS_HEADER
# freeze: 1 where any gaussian may freeze at the check; static: the static count after it; held:
# the moving gaussians held back from freezing (all of them above the gap without a hold region)
STATIC_CHECKS_HEADER = "iteration,time_gap_db,freeze,static,held\n"


def restart_static_checks(out_dir: Path, start: int) -> None:
    """static_checks.csv as of iteration ``start``: a fresh run's is removed, a resumed run's
    keeps the rows up to ``start`` (a file of another header is started over)."""
    path = out_dir / STATIC_CHECKS_FILE
    if not path.is_file():
        return
    lines = path.read_text().splitlines(keepends=True)
    if start <= 0 or not lines or lines[0] != STATIC_CHECKS_HEADER:
        path.unlink()
        return
    keep = [ln for ln in lines[1:] if ln.split(",", 1)[0].isdigit() and int(ln.split(",", 1)[0]) <= start]
    path.write_text(STATIC_CHECKS_HEADER + "".join(keep))


def check_static(tr: Trainer, it: int, cfg: ReconstructionConfig, data: ImageCache, bg: torch.Tensor,
                  backend: str, out_dir: Path) -> None:
    """On the schedule (``static_*`` settings), re-measure which gaussians move: the still ones
    skip the network from the next step, the ones that move again are woken up. Above the time
    gap nothing new freezes, or with ``static_hold_error`` nothing among the gaussians that draw
    the lagging times' badly rendered pixels (``hold_region``); each check is logged."""
    if cfg.static_threshold <= 0 or tr.deform is None:
        return
    first = cfg.warm_up + cfg.static_from
    if it < first or (it - first) % cfg.static_interval != 0:
        return
    from trase.static_gaussians import (
        FROZEN_WIDTH,
        check_times,
        lagging_times,
        time_gap,
        update_static,
    )

    g = tr.gaussians
    if tr.static is None:
        tr.static = torch.zeros(g.num_gaussians, dtype=torch.bool, device=g.means.device)
        tr.frozen = torch.zeros(g.num_gaussians, FROZEN_WIDTH, device=g.means.device)
    times = check_times([c.time for c in data.cameras])
    gap, held = None, 0
    freeze: bool | torch.Tensor = True
    if cfg.static_time_gap > 0:
        ps, ts = views_psnr(tr, data, times, bg, backend, cfg.near_plane)
        gap = time_gap(ps, ts)
        lagging = lagging_times(ps, ts, cfg.static_time_gap)  # not empty exactly when gap > static_time_gap
        if lagging:
            # held back: the moving rows that would otherwise be free to freeze
            hold = (hold_region(tr, data, lagging, bg, backend, cfg.static_hold_error, cfg.near_plane)
                    if cfg.static_hold_error > 0 else torch.ones_like(tr.static))
            freeze, held = ~hold, int((hold & ~tr.static).sum())
    tr.static, tr.frozen, _ = update_static(tr.deform, g.means.detach(), g.scales.detach(), times,
                                            tr.strategy.extent, cfg.static_threshold, tr.static, tr.frozen, freeze)
    if gap is not None:  # what held the freezing back, check by check
        path = out_dir / STATIC_CHECKS_FILE
        new = not path.exists()
        with path.open("a") as f:
            if new:
                f.write(STATIC_CHECKS_HEADER)
            may_freeze = bool(torch.as_tensor(freeze).any())  # a bool, or the rows free to freeze
            f.write(f"{it},{gap:.3f},{int(may_freeze)},{tr.n_static},{held}\n")


@torch.no_grad()
def views_psnr(tr: Trainer, data: ImageCache, times: list[float], bg: torch.Tensor, backend: str,
                near: float) -> tuple[list[float], list[float]]:
    """PSNR (dB) and time of each training view at ``times`` (a static check's)."""
    keep = {round(float(t), 9) for t in times}
    deformation = tr.deformation()
    ps, ts = [], []
    for cam, gt in zip(data.cameras, data.images):
        if round(float(cam.time), 9) in keep:
            ps.append(psnr(render_view(tr.gaussians, deformation, cam, bg, backend, near=near)[0].color.clamp(0, 1), gt))
            ts.append(cam.time)
    return ps, ts


def hold_region(tr: Trainer, data: ImageCache, lagging: set[float], bg: torch.Tensor, backend: str,
                 error: float, near: float) -> torch.Tensor:
    """[N] bool: the gaussians that draw a pixel of a lagging time's training view whose colour
    is off by more than ``error`` (mean absolute error over the channels): the gradient of that
    region's error reaches their opacity or their colour (the colour's as well, since the
    rasterizer caps a pixel's alpha and an opaque gaussian's opacity gets no gradient where it
    is capped). Where a motion is not learned, these are typically the mover where it is drawn
    and what is drawn where it should be."""
    from trase.deformation import deformed
    from trase.render import rasterize

    g = tr.gaussians
    deformation = tr.deformation()
    hold = torch.zeros(g.num_gaussians, dtype=torch.bool, device=g.means.device)
    for cam, gt in zip(data.cameras, data.images):
        if round(float(cam.time), 9) not in lagging:
            continue
        with torch.no_grad():
            means, quats, scales = deformed(g, deformation, float(cam.time))
        colors = g.sh_for_render().detach().clone().requires_grad_(True)  # [N, K, 3]
        opacity = g.opacities.detach().clone().requires_grad_(True)  # [N]
        with torch.enable_grad():
            out = rasterize(means, quats, scales, opacity, cam, colors=colors, sh_degree=g.active_sh_degree,
                            background=bg, backend=backend, near=near)
            err = (out.color - gt).abs().mean(dim=-1)  # [H, W]
            region = (out.color.detach().clamp(0, 1) - gt).abs().mean(dim=-1) > error
            if not bool(region.any()):
                continue
            (err * region).sum().backward()
        hold |= (opacity.grad != 0) | (colors.grad != 0).flatten(1).any(dim=1)
    return hold


__all__ = ["STATIC_CHECKS_FILE", "STATIC_CHECKS_HEADER", "check_static", "hold_region", "restart_static_checks",
           "views_psnr"]
