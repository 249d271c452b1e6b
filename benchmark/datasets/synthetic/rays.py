"""Per-pixel viewing rays for a ``trase.camera.Camera``, inverting its lens model exactly.

Pixel centres are at (i + 0.5, j + 0.5) (the Camera contract). K is applied to *distorted*
normalised coordinates, so a pixel is first mapped through K^-1 and then undistorted:
nerfies radial/tangential distortion by Newton's method on the 2-D distortion map, the
equidistant fisheye by Newton's method on r_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6).
Rays whose inversion does not converge (outside the lens model's monotonic range) are flagged
invalid; the renderer leaves them empty.
"""

from __future__ import annotations

import numpy as np

from trase.camera import Camera


def pixel_grid(width: int, height: int) -> np.ndarray:
    """[H*W, 2] pixel-centre coordinates (u, v), row-major."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    return np.stack([u.ravel(), v.ravel()], axis=1)


def _undistort_pinhole(cam: Camera, xd: np.ndarray, yd: np.ndarray, iters: int = 20):
    """Invert the nerfies/OpenCV radial-tangential map by Newton's method -> (x, y, ok)."""
    k1, k2, k3 = cam.radial
    p1, p2 = cam.tangential
    x, y = xd.copy(), yd.copy()
    for it in range(iters):
        if it and np.abs(cam.distort(np.stack([x, y], axis=1)) - np.stack([xd, yd], axis=1)).max() < 1e-13:
            break
        r2 = x * x + y * y
        rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d rad / d r2
        fx = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
        fy = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
        a = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
        b = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
        c = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
        d = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
        det = a * d - b * c
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        x = x - (d * fx - b * fy) / det
        y = y - (a * fy - c * fx) / det
    xy = np.stack([x, y], axis=1)
    err = np.abs(cam.distort(xy) - np.stack([xd, yd], axis=1)).max(axis=1)
    return x, y, np.isfinite(err) & (err < 1e-9)


def _undistort_fisheye(cam: Camera, rd: np.ndarray, iters: int = 30):
    """Invert r_d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6) -> (theta, ok)."""
    k1, k2, k3 = cam.radial
    th = rd.copy()
    for _ in range(iters):
        t2 = th * th
        f = th * (1.0 + t2 * (k1 + t2 * (k2 + t2 * k3))) - rd
        df = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + 7.0 * k3 * t2))
        th = th - f / np.where(np.abs(df) < 1e-12, 1e-12, df)
    t2 = th * th
    f = th * (1.0 + t2 * (k1 + t2 * (k2 + t2 * k3))) - rd
    df = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + 7.0 * k3 * t2))
    ok = np.isfinite(th) & (np.abs(f) < 1e-9) & (df > 0) & (th >= 0) & (th < np.pi)
    return th, ok


def camera_rays(cam: Camera, uv: np.ndarray | None = None):
    """Rays through pixels ``uv`` [M, 2] (default: every pixel centre, row-major).

    Returns (origin [3], dirs [M, 3] unit world directions, zc [M] camera-space z of each unit
    direction, so depth = distance * zc, valid [M] bool).
    """
    if uv is None:
        # camera-space rays depend only on intrinsics and lens: reuse them across a rig
        key = (cam.width, cam.height, cam.K.tobytes(), cam.radial, cam.tangential, cam.fisheye)
        dc, ok = _grid_dirs(key, cam)
    else:
        dc, ok = _camera_dirs(cam, np.asarray(uv, dtype=np.float64).reshape(-1, 2))
    c2w = cam.c2w
    dirs = dc @ c2w[:3, :3].T
    return c2w[:3, 3].copy(), dirs, dc[:, 2], ok


_GRID_CACHE: dict = {}


def _grid_dirs(key, cam: Camera):
    if key not in _GRID_CACHE:
        if len(_GRID_CACHE) > 8:
            _GRID_CACHE.clear()
        dc, ok = _camera_dirs(cam, pixel_grid(cam.width, cam.height))
        dc.setflags(write=False)
        ok.setflags(write=False)
        _GRID_CACHE[key] = (dc, ok)
    return _GRID_CACHE[key]


def _camera_dirs(cam: Camera, uv: np.ndarray):
    """Unit camera-space directions [M, 3] and validity [M] of pixels uv [M, 2]."""
    K = cam.K
    yd = (uv[:, 1] - K[1, 2]) / K[1, 1]
    xd = (uv[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    if cam.fisheye:
        rd = np.hypot(xd, yd)
        th, ok = _undistort_fisheye(cam, rd)
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.where(rd > 1e-15, np.sin(th) / np.where(rd > 1e-15, rd, 1.0), 1.0)
        dc = np.stack([xd * k, yd * k, np.cos(th)], axis=1)
    else:
        if any(cam.radial) or any(cam.tangential):
            x, y, ok = _undistort_pinhole(cam, xd, yd)
        else:
            x, y, ok = xd, yd, np.ones(len(xd), dtype=bool)
        dc = np.stack([x, y, np.ones_like(x)], axis=1)
    dc = np.where(ok[:, None], dc, np.array([0.0, 0.0, 1.0]))
    dc /= np.linalg.norm(dc, axis=1, keepdims=True)
    return dc, ok
