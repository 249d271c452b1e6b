"""EWA projection of 3D gaussians to screen-space 2D gaussians (shared by the CPU backends).

Standard 3DGS math: Sigma = R S S^T R^T, cov2d = J W Sigma W^T J^T + 0.3 I (low-pass
dilation), conic = cov2d^-1, screen extent = ceil(3 sqrt(lambda_max)) pixels. The Jacobian
uses the camera-space point with x/z and y/z clamped to 1.3x the field of view (measured from
the principal point on each side, so off-centre principal points work), as 3DGS and gsplat do.
It runs in float64 (cheap, vectorised over gaussians) so that huge or tiny scales do not lose
the determinant to cancellation; results are cast to the compositing dtype.
"""

from __future__ import annotations

import dataclasses
import math

import torch

from trase.camera import Camera

EPS2D = 0.3  # low-pass dilation added to the 2D covariance diagonal (pixels^2)


@dataclasses.dataclass
class Projected:
    means2d: torch.Tensor  # [N, 2] pixel coordinates (top-left corner at 0, centres at i + 0.5)
    conics: torch.Tensor  # [N, 3] (a, b, c) of the inverse 2D covariance [[a, b], [b, c]]
    depths: torch.Tensor  # [N] camera z
    radii: torch.Tensor  # [N] int64 screen radius in pixels, 0 = culled (no grad)
    rects: torch.Tensor  # [N, 4] int64 tile ranges (x0, x1, y0, y1), half-open, empty if culled


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """[N, 4] wxyz (any norm; zero -> identity) -> [N, 3, 3] rotation matrices."""
    q = quats / quats.norm(dim=1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=1,
    ).reshape(-1, 3, 3)


def tile_grid(camera: Camera, tile_size: int) -> tuple[int, int]:
    """(tiles across, tiles down)."""
    return (camera.width + tile_size - 1) // tile_size, (camera.height + tile_size - 1) // tile_size


def jacobian_clamp(camera: Camera) -> tuple[float, float, float, float]:
    """(x/z low, high, y/z low, high) at which the EWA Jacobian is evaluated: the field of view
    widened by 0.3x its half-tangent on each side of the principal point (3DGS, gsplat)."""
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    tan_x, tan_y = 0.5 * camera.width / fx, 0.5 * camera.height / fy
    return (-(cx / fx + 0.3 * tan_x), (camera.width - cx) / fx + 0.3 * tan_x,
            -(cy / fy + 0.3 * tan_y), (camera.height - cy) / fy + 0.3 * tan_y)


def screen_rects(
    means2d: torch.Tensor,  # [N, 2] (no grad)
    lam: torch.Tensor,  # [N] largest eigenvalue of the dilated 2D covariance
    ok: torch.Tensor,  # [N] bool: not culled
    camera: Camera,
    tile_size: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """-> (radii [N] int64, rects [N, 4] int64 half-open tile ranges (x0, x1, y0, y1));
    radius ceil(3 sqrt(lam)) pixels, 0 and an empty rect for culled or off-screen gaussians."""
    radius = torch.ceil(3.0 * torch.sqrt(lam))
    radius = torch.where(ok & torch.isfinite(radius), radius, torch.zeros_like(radius))
    gx, gy = tile_grid(camera, tile_size)
    big = float(max(gx, gy) + 2)

    def tiles(lo: torch.Tensor, hi: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor]:
        t0 = torch.floor(lo / tile_size).clamp(-1.0, big).to(torch.int64).clamp(0, n)
        t1 = (torch.floor(hi / tile_size) + 1).clamp(-1.0, big).to(torch.int64).clamp(0, n)
        return t0, t1

    uu, vv = means2d[:, 0], means2d[:, 1]
    x0, x1 = tiles(uu - radius, uu + radius, gx)
    y0, y1 = tiles(vv - radius, vv + radius, gy)
    empty = (radius <= 0) | (x1 <= x0) | (y1 <= y0)
    rects = torch.stack([x0, x1, y0, y1], dim=1)
    rects[empty] = 0
    radii = torch.where(empty, torch.zeros_like(radius), radius).to(torch.int64)
    return radii, rects


def project_gaussians(
    means: torch.Tensor,  # [N, 3]
    quats: torch.Tensor,  # [N, 4] wxyz
    scales: torch.Tensor,  # [N, 3] positive
    camera: Camera,
    near: float = 0.01,
    tile_size: int = 16,
    dtype: torch.dtype | None = None,
) -> Projected:
    """Differentiable (torch autograd) projection; culled gaussians get radius 0 and finite,
    zero-gradient values."""
    out_dtype = dtype or means.dtype
    dev = means.device
    f64 = torch.float64
    R_w = torch.as_tensor(camera.w2c[:3, :3], dtype=f64, device=dev)
    t_w = torch.as_tensor(camera.w2c[:3, 3], dtype=f64, device=dev)
    p = means.to(f64) @ R_w.T + t_w  # [N, 3] camera space
    z = p[:, 2]
    in_front = z > near
    z_safe = torch.where(in_front, z, torch.ones_like(z))  # keeps culled gradients finite

    fx, fy, cx, cy, skew = camera.fx, camera.fy, camera.cx, camera.cy, float(camera.K[0, 1])
    xn, yn = p[:, 0] / z_safe, p[:, 1] / z_safe
    u = fx * xn + skew * yn + cx
    v = fy * yn + cy

    # Jacobian of the projection at the (FOV-clamped) point
    xlo, xhi, ylo, yhi = jacobian_clamp(camera)
    xc = xn.clamp(xlo, xhi)
    yc = yn.clamp(ylo, yhi)
    zero = torch.zeros_like(z)
    J = torch.stack(
        [fx / z_safe, skew / z_safe, -(fx * xc + skew * yc) / z_safe, zero, fy / z_safe, -fy * yc / z_safe],
        dim=1,
    ).reshape(-1, 2, 3)

    Rg = quat_to_rotmat(quats.to(f64))
    M = Rg * scales.to(f64)[:, None, :]  # [N, 3, 3] = R diag(s)
    sigma = M @ M.transpose(1, 2)
    JW = J @ R_w  # [N, 2, 3]
    cov = JW @ sigma @ JW.transpose(1, 2)  # [N, 2, 2]
    a = cov[:, 0, 0] + EPS2D
    b = cov[:, 0, 1]
    c = cov[:, 1, 1] + EPS2D
    det = a * c - b * b
    ok = in_front & (det > 0) & torch.isfinite(det)
    det_safe = torch.where(ok, det, torch.ones_like(det))
    conics = torch.stack([c / det_safe, -b / det_safe, a / det_safe], dim=1)
    conics = torch.where(ok[:, None], conics, torch.zeros_like(conics))
    means2d = torch.stack([u, v], dim=1)
    means2d = torch.where(ok[:, None], means2d, torch.zeros_like(means2d))

    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam = mid + torch.sqrt((mid * mid - det).clamp_min(0.1))
        radii, rects = screen_rects(means2d.detach(), lam, ok, camera, tile_size)
    assert math.isfinite(near)
    return Projected(
        means2d=means2d.to(out_dtype),
        conics=conics.to(out_dtype),
        depths=z.to(out_dtype),
        radii=radii,
        rects=rects,
    )
