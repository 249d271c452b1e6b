"""Fit the ground-truth gaussians' silhouettes to the exact ones, on the training cameras.

Why: ``geometry.npz`` stands in for a perfect reconstruction, so rendering an object's
gaussians alone (alpha >= 0.5, the segmentation rule) should give the object's true outline.
Disks placed on the surface do not: the rasterizer's fixed 0.3 px^2 low-pass and the pile-up
of disks along grazing rays push the outline about a pixel outwards, which is most of a small
object (a 40-pixel ball loses IoU 0.3). The push is a matter of *pixels*, so each object's
disks sink below its surface by an inset in pixels of the rig's training cameras
(``pixel_footprint``), and the inset is chosen per object (``calibrate_insets``) by rendering
the object alone at a few training cameras and comparing with its exact ray-cast silhouette
(the object alone in the world, so occlusion plays no part). Test cameras are never used.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from .shapes import Room
from .world import World, render

INSET_CANDIDATES = tuple(np.round(np.arange(0.0, 2.51, 0.125), 3))  # pixels
CALIBRATION_VIEWS = 8  # training cameras used per scene (spread over the sequence)


def pixel_footprint(cameras: Sequence) -> Callable[[np.ndarray], np.ndarray]:
    """points [N, 3] -> [N] metres per pixel there: median over ``cameras`` (in front of
    them) of depth / focal length (pinhole cameras of the loader, training resolution)."""
    cams = list(cameras)
    if not cams:
        raise ValueError("pixel_footprint needs at least one camera")

    def footprint(points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, np.float64)
        per_cam = []
        for cam in cams:
            z = p @ cam.w2c[2, :3] + cam.w2c[2, 3]
            f = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
            per_cam.append(np.where(z > 1e-6, z / f, np.nan))
        stack = np.stack(per_cam)  # [C, N]
        seen = np.isfinite(stack).any(axis=0)
        out = np.zeros(len(p))  # behind every camera: no inset
        if seen.any():
            out[seen] = np.nanmedian(stack[:, seen], axis=0)
        return out

    return footprint


def spread(items: Sequence, k: int) -> list:
    """``k`` items evenly spread over the sequence (all when there are fewer)."""
    n = len(items)
    if n <= k:
        return list(items)
    return [items[round(i * (n - 1) / (k - 1))] for i in range(k)] if k > 1 else [items[0]]


def _alpha(geom: dict, camera, t_index: int) -> np.ndarray:
    """[H, W] alpha of the gaussians of ``geom`` at tabulated time index ``t_index``."""
    import torch

    from trase.render import rasterize

    q = torch.as_tensor(geom["quats"], dtype=torch.float32)
    quats = q / q.norm(dim=1, keepdim=True) + torch.as_tensor(geom["d_rot"][t_index])
    scales = torch.clamp(torch.exp(torch.as_tensor(geom["log_scales"])) + torch.as_tensor(geom["d_scale"][t_index]),
                         min=1e-8)
    means = torch.as_tensor(geom["means"]) + torch.as_tensor(geom["d_xyz"][t_index])
    opac = torch.sigmoid(torch.as_tensor(geom["opacity_logits"]))
    with torch.no_grad():
        out = rasterize(means, quats, scales, opac, camera, features=torch.zeros(means.shape[0], 1))
    return out.alpha.numpy()


def silhouette_errors(world: World, name: str, geoms: Sequence[dict], cameras: Sequence, times: np.ndarray
                      ) -> np.ndarray:
    """[len(geoms)] pixels rendered wrong (alpha >= 0.5 vs the exact silhouette of object
    ``name`` alone), summed over ``cameras`` at their own times."""
    alone = World([world.by_name(name)], world.seed)
    err = np.zeros(len(geoms))
    for cam in cameras:
        ti = int(np.argmin(np.abs(times - cam.time)))
        truth = render(alone, cam, cam.time)[2] > 0
        for j, g in enumerate(geoms):
            err[j] += np.count_nonzero((_alpha(g, cam, ti) >= 0.5) != truth)
    return err


def calibrate_insets(world: World, times: np.ndarray, budget: int, cameras: Sequence,
                     candidates: Sequence[float] = INSET_CANDIDATES,
                     n_views: int = CALIBRATION_VIEWS) -> tuple[dict[str, float], dict]:
    """Per object (room excluded): the inset in pixels whose rendered outline best matches
    the exact one at ``n_views`` training ``cameras`` -> ({name: inset_px}, report).

    The report holds, per object, the silhouette error (wrong pixels) at inset 0 and at the
    chosen inset, and the IoU of the chosen one."""
    from .gaussians import build_geometry

    footprint = pixel_footprint(cameras)
    views = spread(list(cameras), n_views)
    times = np.asarray(times, np.float64)
    # tabulate only the first time (it fixes the canonical gaussians) and the calibration
    # views' nearest times: the same gaussians at those times as the full table, at a
    # fraction of the cost on long sequences
    times = times[sorted({0, *(int(np.argmin(np.abs(times - c.time))) for c in views)})]
    insets, report = {}, {}
    for obj in world.objects:
        if isinstance(obj.shape, Room):
            continue
        geoms = [build_geometry(world, times, budget, inset={obj.name: c}, footprint=footprint, only=obj.name)
                 for c in candidates]
        err = silhouette_errors(world, obj.name, geoms, views, times)
        best = int(np.argmin(err))  # ties: the smallest inset
        insets[obj.name] = float(candidates[best])
        report[obj.name] = {"inset_px": float(candidates[best]), "wrong_px": int(err[best]),
                            "wrong_px_at_0": int(err[0])}
    return insets, report
