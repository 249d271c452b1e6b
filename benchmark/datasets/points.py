"""Initial point clouds: read PLY / npy files, or sample camera frustums when none exists."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmark.datasets.errors import fail
from trase.camera import Camera


def read_points(path: Path | str) -> tuple[np.ndarray, np.ndarray | None]:
    """(points [N, 3] float64, colours [N, 3] in [0, 1] or None) from .ply or .npy."""
    path = Path(path)
    if not path.is_file():
        raise fail(path, "missing point cloud")
    colors = None
    if path.suffix == ".npy":
        try:
            pts = np.load(path)
        except (ValueError, OSError) as exc:
            raise fail(path, f"cannot read ({exc.__class__.__name__})") from None
    elif path.suffix == ".ply":
        from plyfile import PlyData

        try:
            v = PlyData.read(str(path))["vertex"]
        except Exception as exc:  # noqa: BLE001 - plyfile raises several unrelated types
            raise fail(path, f"cannot read PLY vertices ({exc.__class__.__name__})") from None
        names = v.data.dtype.names or ()
        if not {"x", "y", "z"} <= set(names):
            raise fail(path, "PLY vertices have no x, y, z")
        pts = np.stack([v["x"], v["y"], v["z"]], axis=1)
        if {"red", "green", "blue"} <= set(names):
            colors = np.stack([v["red"], v["green"], v["blue"]], axis=1).astype(np.float64) / 255.0
    else:
        raise fail(path, "point cloud must be .ply or .npy")
    pts = np.asarray(pts, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise fail(path, f"points must be [N, 3], got shape {pts.shape}")
    if not np.isfinite(pts).all():
        raise fail(path, "points contain NaN or Inf")
    return pts, colors


def frustum_points(cameras: list[Camera], depth_range: tuple[float, float] | None,
                   n: int = 20000, seed: int = 0) -> np.ndarray:
    """[n, 3] points sampled uniformly over pixels and depths of the given pinhole cameras.

    Used when a sequence has no SfM cloud. ``depth_range`` (near, far) comes from the data
    (Neu3D bounds); without one the rig's size sets it: [1, 10] x its diameter (1 when all
    centres coincide). Deterministic for a seed.
    """
    rng = np.random.default_rng(seed)
    if depth_range is None:
        c = np.stack([cam.center for cam in cameras])
        diam = float(np.max(np.linalg.norm(c[:, None] - c[None], axis=-1))) if len(c) > 1 else 0.0
        diam = diam if diam > 1e-9 else 1.0
        depth_range = (diam, 10.0 * diam)
    near, far = depth_range
    which = rng.integers(0, len(cameras), size=n)
    out = np.empty((n, 3))
    for k, cam in enumerate(cameras):
        idx = np.flatnonzero(which == k)
        if idx.size == 0:
            continue
        uv = rng.uniform([0.0, 0.0], [cam.width, cam.height], size=(idx.size, 2))
        depth = rng.uniform(near, far, size=idx.size)
        out[idx] = cam.unproject(uv, depth)
    return out
