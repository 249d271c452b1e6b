"""Per-pixel correspondence between two views of a dynamic scene through its frozen geometry.

``backward_warp`` carries a label image of view A into view B: each pixel of B where the
geometry is solid is lifted to its surface point at B's time (rendered depth), moved to A's
time by the gaussians' own displacement (the deformation's means at A's time minus those at
B's, rendered as a 3-channel feature image and divided by the accumulated alpha, so a pixel
moves as the gaussians it shows move), projected into A, and kept where A sees that point
(its depth within a tolerance of A's rendered depth there). The label of A at that pixel is
B's warped label; elsewhere it is unknown (-1). ``visible_gaussians`` says which gaussians a
view shows on its surface, and at which pixel (the tracker's votes for merging tracks).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from trase.camera import Camera
from trase.deformation import deformed
from trase.render import rasterize

# a pixel counts as showing a surface where the accumulated alpha reaches this (the project's
# rendering threshold for masks: trase.segment renders alpha >= 0.5 as the object)
MIN_ALPHA = 0.5
# a warped point is visible in A when its depth there is at most this far (relative) behind
# A's rendered depth: expected depth blends the front surface with what lies behind it at edges,
# and 5% of the depth is well above the blend's error on solid surfaces and well below the gap
# between an object and the wall behind it in the scenes the benchmark has
DEPTH_TOLERANCE = 0.05


@dataclasses.dataclass
class ViewGeometry:
    """What a view renders of the frozen geometry: depth and alpha [H, W], and the means of the
    deformed gaussians at its time [N, 3]."""

    camera: Camera
    depth: np.ndarray
    alpha: np.ndarray
    means: torch.Tensor


@torch.no_grad()
def view_geometry(gaussians, deformation, camera: Camera) -> ViewGeometry:
    """Render ``camera``'s depth and alpha at its time."""
    m, q, s = deformed(gaussians, deformation, camera.time)
    m, q, s = m.detach(), q.detach(), s.detach()
    o = gaussians.opacities.detach()
    if m.shape[0] == 0:
        z = np.zeros((camera.height, camera.width), np.float32)
        return ViewGeometry(camera, z, z.copy(), m)
    out = rasterize(m, q, s, o, camera, features=torch.zeros(m.shape[0], 1, dtype=m.dtype))
    return ViewGeometry(camera, out.depth.cpu().numpy(), out.alpha.cpu().numpy(), m)


@torch.no_grad()
def backward_warp(gaussians, deformation, prev: ViewGeometry, cur: ViewGeometry, labels_prev: np.ndarray,
                  depth_tolerance: float = DEPTH_TOLERANCE, min_alpha: float = MIN_ALPHA) -> np.ndarray:
    """[H_cur, W_cur] int64: ``labels_prev`` ([H_prev, W_prev], values >= 0) carried into the
    current view; -1 where the current pixel shows no surface, its point leaves the previous
    view, or the previous view does not see it (occluded there)."""
    cam_b, cam_a = cur.camera, prev.camera
    out = np.full((cam_b.height, cam_b.width), -1, np.int64)
    n = gaussians.num_gaussians
    if n == 0:
        return out
    solid = (cur.alpha >= min_alpha) & (cur.depth > 0)
    if not solid.any():
        return out
    # per-pixel displacement from the current time to the previous one, as the gaussians move
    disp = (prev.means - cur.means).to(cur.means.dtype)
    m, q, s = deformed(gaussians, deformation, cam_b.time)
    rendered = rasterize(m.detach(), q.detach(), s.detach(), gaussians.opacities.detach(), cam_b, features=disp)
    alpha = np.maximum(rendered.alpha.cpu().numpy(), 1e-6)
    flow = rendered.features.cpu().numpy().astype(np.float64) / alpha[..., None]  # [H, W, 3]
    rows, cols = np.nonzero(solid)
    uv = np.stack([cols + 0.5, rows + 0.5], 1).astype(np.float64)  # pixel centres
    pts = cam_b.unproject(uv, cur.depth[rows, cols]) + flow[rows, cols]
    uv_a, z_a = cam_a.project(pts)
    ca = np.floor(uv_a[:, 0])
    ra = np.floor(uv_a[:, 1])
    inside = np.isfinite(ca) & np.isfinite(ra) & (z_a > 0) & (ca >= 0) & (ca < cam_a.width) & (ra >= 0) & \
        (ra < cam_a.height)
    ca = np.where(inside, ca, 0).astype(np.int64)
    ra = np.where(inside, ra, 0).astype(np.int64)
    d_a = prev.depth[ra, ca]
    seen = inside & (prev.alpha[ra, ca] >= min_alpha) & (d_a > 0) & (z_a <= d_a * (1.0 + depth_tolerance))
    out[rows[seen], cols[seen]] = labels_prev[ra[seen], ca[seen]]
    return out


def visible_gaussians(view: ViewGeometry, depth_tolerance: float = DEPTH_TOLERANCE,
                      min_alpha: float = MIN_ALPHA) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(gaussians [M], rows [M], cols [M]): the gaussians whose centre (at the view's time)
    lies on the surface the view shows: inside the image on a solid pixel (alpha >= ``min_alpha``)
    with its depth within ``depth_tolerance`` (relative) of the rendered depth there; the pixel
    each falls on."""
    cam = view.camera
    empty = np.zeros(0, np.int64)
    if view.means.shape[0] == 0:
        return empty, empty, empty
    uv, z = cam.project(view.means.cpu().numpy().astype(np.float64))
    c, r = np.floor(uv[:, 0]), np.floor(uv[:, 1])
    inside = np.isfinite(c) & np.isfinite(r) & (z > 0) & (c >= 0) & (c < cam.width) & (r >= 0) & (r < cam.height)
    idx = np.flatnonzero(inside)
    r, c, z = r[idx].astype(np.int64), c[idx].astype(np.int64), z[idx]
    d = view.depth[r, c]
    on = (view.alpha[r, c] >= min_alpha) & (d > 0) & (np.abs(z - d) <= depth_tolerance * d)
    return idx[on], r[on], c[on]


__all__ = ["DEPTH_TOLERANCE", "MIN_ALPHA", "ViewGeometry", "backward_warp", "view_geometry", "visible_gaussians"]
