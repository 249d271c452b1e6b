"""Exact ray casting of the synthetic scenes: shape intersections and lens inversion."""

from __future__ import annotations

import numpy as np
import pytest

from benchmark.datasets.synthetic.rays import camera_rays, pixel_grid
from benchmark.datasets.synthetic.shapes import Box, Cylinder, Room, Sphere, Torus
from benchmark.datasets.synthetic.world import build_world, render
from trase.camera import Camera, intrinsics, look_at


def _implicit(shape, p):
    """Signed-ish implicit function of each shape (0 on the surface)."""
    if isinstance(shape, Sphere):
        return np.linalg.norm(p, axis=1) - 1.0
    if isinstance(shape, (Box, Room)):
        return np.abs(p).max(axis=1) - 1.0
    if isinstance(shape, Cylinder):
        return np.maximum(np.hypot(p[:, 0], p[:, 1]) - 1.0, np.abs(p[:, 2]) - 1.0)
    q = np.hypot(np.hypot(p[:, 0], p[:, 1]) - 1.0, p[:, 2])
    return q - shape.minor


@pytest.mark.parametrize("shape", [Sphere(), Box(), Cylinder(), Torus(0.3)], ids=lambda s: s.kind)
def test_intersection_is_first_surface_point(shape):
    rng = np.random.default_rng(0)
    M = 3000
    o = rng.normal(size=(M, 3))
    o = o / np.linalg.norm(o, axis=1, keepdims=True) * 3.0
    target = rng.uniform(-1.4, 1.4, size=(M, 3))
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    s = shape.intersect(o, d)
    hit = np.isfinite(s)
    assert 0.2 < hit.mean() < 1.0
    p = o[hit] + s[hit, None] * d[hit]
    np.testing.assert_allclose(_implicit(shape, p), 0.0, atol=1e-7)
    # no earlier crossing: sample the ray before the hit, everything is outside
    for frac in np.linspace(0.0, 0.999, 60):
        q = o[hit] + (s[hit] * frac)[:, None] * d[hit]
        assert (_implicit(shape, q) > -1e-9).all()
    # misses: the ray never enters the shape
    for tt in np.linspace(0.0, 6.0, 400):
        q = o[~hit] + tt * d[~hit]
        assert (_implicit(shape, q) > -1e-9).all()


def test_room_is_hit_from_inside():
    rng = np.random.default_rng(1)
    o = rng.uniform(-0.5, 0.5, size=(500, 3))
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    s = Room().intersect(o, d)
    assert np.isfinite(s).all()
    np.testing.assert_allclose(np.abs(o + s[:, None] * d).max(axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize(
    "lens",
    [
        {},
        {"radial": (-0.05, 0.01, 0.001), "tangential": (0.002, -0.001)},
        {"radial": (0.02, -0.004, 0.0), "fisheye": True},
    ],
    ids=["pinhole", "nerfies", "fisheye"],
)
def test_rays_invert_the_lens(lens):
    W, H = 80, 60
    f = 70.0 if not lens.get("fisheye") else W / 2 / 0.9
    cam = Camera(intrinsics(f, f * 1.01, W / 2 + 1.3, H / 2 - 0.7, skew=0.2), look_at([0.5, -3, 1], [0, 0, 0.4]),
                 W, H, **lens)
    origin, dirs, zc, ok = camera_rays(cam)
    assert ok.all()
    pts = origin + dirs * 2.5
    uv, depth = cam.project(pts)
    np.testing.assert_allclose(uv, pixel_grid(W, H), atol=1e-6)
    np.testing.assert_allclose(depth, 2.5 * zc, atol=1e-9)


def test_render_outputs_and_depth():
    world = build_world(0)
    cam = Camera(intrinsics(60, 60, 40, 30), look_at([0.0, -3.0, 1.2], [0, 0.3, 0.4]), 80, 60)
    rgb, depth, ids = render(world, cam, 0.3)
    assert rgb.shape == (60, 80, 3) and rgb.dtype == np.uint8
    assert ids.dtype == np.uint16 and (ids > 0).all()  # inside the room every ray hits
    assert set(np.unique(ids)) >= {1, 2, 3, 6}
    # depth is camera z: unprojecting a pixel at its depth lands on the object's surface
    c = world.by_name("blob").pose(0.3)
    R, centre, S = c
    v, u = np.argwhere(ids == world.by_name("blob").id)[0]
    p = cam.unproject(np.array([[u + 0.5, v + 0.5]]), depth[v, u : u + 1])[0]
    assert np.linalg.norm(((p - centre) @ R) / S) == pytest.approx(1.0, abs=1e-4)
