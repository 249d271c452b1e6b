"""Canonical shapes: exact ray intersection and surface sampling in the shape's own frame.

Every shape lives in a unit-sized local frame (sphere of radius 1, box [-1, 1]^3, cylinder of
radius 1 with z in [-1, 1], torus around z with major radius 1); objects place it in the world
with a per-time affine map (rotation, translation, per-axis scale), so a ray is intersected in
local coordinates and the ray parameter carries over unchanged (see ``world.py``).

``intersect(o, d)`` takes local origins ``o`` [M, 3] and *unit* local directions ``d`` [M, 3]
and returns the distance ``s`` [M] to the first hit in front of the origin (``inf`` on a miss).
``normal(p)`` gives the outward local normal at surface points; ``sample(n)`` returns
roughly ``n`` well-spread surface points with normals (for the ground-truth gaussians) and the
local area of the surface.
"""

from __future__ import annotations

import math

import numpy as np

EPS = 1e-9


def _first_positive(s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """Per ray, the smaller of two candidate distances that is > EPS (inf when none)."""
    s1 = np.where(s1 > EPS, s1, np.inf)
    s2 = np.where(s2 > EPS, s2, np.inf)
    return np.minimum(s1, s2)


class Sphere:
    """Unit sphere."""

    kind = "sphere"
    bound = 1.0  # radius of a local bounding sphere centred at the origin

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        b = np.einsum("ij,ij->i", o, d)
        c = np.einsum("ij,ij->i", o, o) - 1.0
        disc = b * b - c
        ok = disc >= 0
        root = np.sqrt(np.where(ok, disc, 0.0))
        s = _first_positive(-b - root, -b + root)
        return np.where(ok, s, np.inf)

    def normal(self, p: np.ndarray) -> np.ndarray:
        return p / np.linalg.norm(p, axis=1, keepdims=True)

    def sample(self, n: int) -> tuple[np.ndarray, np.ndarray, float]:
        # Fibonacci lattice: near-uniform, deterministic.
        i = np.arange(n) + 0.5
        z = 1.0 - 2.0 * i / n
        r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
        phi = i * math.pi * (3.0 - math.sqrt(5.0))
        p = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
        return p, p.copy(), 4.0 * math.pi


class Box:
    """Axis-aligned cube [-1, 1]^3 (solid, seen from outside)."""

    kind = "box"
    bound = math.sqrt(3.0)

    def _slabs(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t1 = (-1.0 - o) * inv
            t2 = (1.0 - o) * inv
        # d == 0: the slab is either always (inside) or never crossed.
        inside = np.abs(o) <= 1.0
        zero = d == 0
        t1 = np.where(zero, np.where(inside, -np.inf, np.inf), t1)
        t2 = np.where(zero, np.where(inside, np.inf, -np.inf), t2)
        return np.minimum(t1, t2).max(axis=1), np.maximum(t1, t2).min(axis=1)

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        tnear, tfar = self._slabs(o, d)
        s = np.where(tnear > EPS, tnear, tfar)
        return np.where((tnear <= tfar) & (s > EPS), s, np.inf)

    def normal(self, p: np.ndarray) -> np.ndarray:
        axis = np.argmax(np.abs(p), axis=1)
        n = np.zeros_like(p)
        rows = np.arange(len(p))
        n[rows, axis] = np.sign(p[rows, axis])
        return n

    def sample(self, n: int) -> tuple[np.ndarray, np.ndarray, float]:
        per_face = max(1, n // 6)
        k = max(1, round(math.sqrt(per_face)))
        g = (np.arange(k) + 0.5) / k * 2.0 - 1.0
        u, v = np.meshgrid(g, g, indexing="ij")
        u, v = u.ravel(), v.ravel()
        pts, nrm = [], []
        for axis in range(3):
            a, b = [x for x in range(3) if x != axis]
            for sign in (-1.0, 1.0):
                p = np.zeros((u.size, 3))
                p[:, axis] = sign
                p[:, a] = u
                p[:, b] = v
                nn = np.zeros_like(p)
                nn[:, axis] = sign
                pts.append(p)
                nrm.append(nn)
        return np.concatenate(pts), np.concatenate(nrm), 24.0


class Cylinder:
    """Capped cylinder of radius 1 around the local z axis, z in [-1, 1]."""

    kind = "cylinder"
    bound = math.sqrt(2.0)

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1]
        c = o[:, 0] ** 2 + o[:, 1] ** 2 - 1.0
        disc = b * b - a * c
        ok = (disc >= 0) & (a > 1e-15)
        root = np.sqrt(np.where(ok, disc, 0.0))
        safe_a = np.where(ok, a, 1.0)
        side = []
        for sgn in (-1.0, 1.0):
            s = (-b + sgn * root) / safe_a
            z = o[:, 2] + s * d[:, 2]
            side.append(np.where(ok & (np.abs(z) <= 1.0), s, np.inf))
        caps = []
        with np.errstate(divide="ignore", invalid="ignore"):
            for zc in (-1.0, 1.0):
                s = (zc - o[:, 2]) / d[:, 2]
                x = o[:, 0] + s * d[:, 0]
                y = o[:, 1] + s * d[:, 1]
                caps.append(np.where((d[:, 2] != 0) & (x * x + y * y <= 1.0), s, np.inf))
        best = np.full(len(o), np.inf)
        for s in side + caps:
            best = np.minimum(best, np.where(s > EPS, s, np.inf))
        return best

    def normal(self, p: np.ndarray) -> np.ndarray:
        radial = np.hypot(p[:, 0], p[:, 1])
        on_cap = np.abs(np.abs(p[:, 2]) - 1.0) < np.abs(radial - 1.0)
        n = np.zeros_like(p)
        n[:, 0] = np.where(on_cap, 0.0, p[:, 0] / np.maximum(radial, 1e-12))
        n[:, 1] = np.where(on_cap, 0.0, p[:, 1] / np.maximum(radial, 1e-12))
        n[:, 2] = np.where(on_cap, np.sign(p[:, 2]), 0.0)
        return n

    def sample(self, n: int) -> tuple[np.ndarray, np.ndarray, float]:
        area_side, area_cap = 4.0 * math.pi, math.pi
        n_side = max(8, int(n * area_side / (area_side + 2 * area_cap)))
        k_h = max(2, round(math.sqrt(n_side / (2 * math.pi) * 2)))
        k_a = max(4, n_side // k_h)
        ang = (np.arange(k_a) + 0.5) / k_a * 2 * math.pi
        hz = (np.arange(k_h) + 0.5) / k_h * 2.0 - 1.0
        A, Z = np.meshgrid(ang, hz, indexing="ij")
        side = np.stack([np.cos(A.ravel()), np.sin(A.ravel()), Z.ravel()], axis=1)
        side_n = side * np.array([1.0, 1.0, 0.0])
        n_cap = max(4, (n - len(side)) // 2)
        i = np.arange(n_cap) + 0.5
        r = np.sqrt(i / n_cap)
        phi = i * math.pi * (3.0 - math.sqrt(5.0))
        disk = np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(n_cap)], axis=1)
        pts, nrm = [side], [side_n]
        for zc in (-1.0, 1.0):
            p = disk.copy()
            p[:, 2] = zc
            pts.append(p)
            nrm.append(np.tile([0.0, 0.0, zc], (n_cap, 1)))
        return np.concatenate(pts), np.concatenate(nrm), area_side + 2 * area_cap


class Torus:
    """Torus around the local z axis: major radius 1, minor radius ``minor``.

    The ray-torus quartic is solved exactly (companion-matrix eigenvalues, then two Newton
    polishing steps), after moving the origin to the bounding sphere to keep it well scaled.
    """

    kind = "torus"

    def __init__(self, minor: float = 0.3):
        self.minor = float(minor)
        self.bound = 1.0 + self.minor

    def _poly(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """[M, 5] quartic coefficients (highest first) of the torus equation along unit d."""
        R2, r2 = 1.0, self.minor**2
        b = 2.0 * np.einsum("ij,ij->i", o, d)
        c = np.einsum("ij,ij->i", o, o) + R2 - r2
        e = d[:, 0] ** 2 + d[:, 1] ** 2
        f = 2.0 * (o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1])
        g = o[:, 0] ** 2 + o[:, 1] ** 2
        return np.stack(
            [
                np.ones_like(b),
                2.0 * b,
                b * b + 2.0 * c - 4.0 * R2 * e,
                2.0 * b * c - 4.0 * R2 * f,
                c * c - 4.0 * R2 * g,
            ],
            axis=1,
        )

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        out = np.full(len(o), np.inf)
        # advance to the bounding sphere (rays that miss it miss the torus)
        ob = o / self.bound
        b = np.einsum("ij,ij->i", ob, d)
        c = np.einsum("ij,ij->i", ob, ob) - 1.0
        disc = b * b - c
        hit = disc >= 0
        if not hit.any():
            return out
        idx = np.nonzero(hit)[0]
        s0 = np.maximum(-b[idx] - np.sqrt(disc[idx]), 0.0) * self.bound
        o2 = o[idx] + s0[:, None] * d[idx]
        coef = self._poly(o2, d[idx])  # [m, 5], monic
        comp = np.zeros((len(idx), 4, 4))
        comp[:, 0, :] = -coef[:, 1:]
        comp[:, 1, 0] = comp[:, 2, 1] = comp[:, 3, 2] = 1.0
        roots = np.linalg.eigvals(comp)  # [m, 4] complex
        real = np.where(np.abs(roots.imag) < 1e-6, roots.real, np.inf)
        real = np.where(real > -1e-7, real, np.inf)
        s = real.min(axis=1)
        finite = np.isfinite(s)
        s = np.where(finite, s, 0.0)
        for _ in range(2):  # Newton polish on the real quartic (inf roots stay inf)
            f = ((((coef[:, 0] * s + coef[:, 1]) * s + coef[:, 2]) * s + coef[:, 3]) * s) + coef[:, 4]
            df = ((4 * coef[:, 0] * s + 3 * coef[:, 1]) * s + 2 * coef[:, 2]) * s + coef[:, 3]
            step = np.where(finite & (np.abs(df) > 1e-12), f / np.where(df == 0, 1.0, df), 0.0)
            s = np.where(finite, s - step, s)
        s = np.where(finite, s + s0, np.inf)
        out[idx] = np.where(s > EPS, s, np.inf)
        return out

    def normal(self, p: np.ndarray) -> np.ndarray:
        q = np.einsum("ij,ij->i", p, p) + 1.0 - self.minor**2
        g = 4.0 * q[:, None] * p
        g[:, :2] -= 8.0 * p[:, :2]
        return g / np.linalg.norm(g, axis=1, keepdims=True)

    def sample(self, n: int) -> tuple[np.ndarray, np.ndarray, float]:
        r = self.minor
        k_v = max(4, round(math.sqrt(n * r)))
        k_u = max(8, n // k_v)
        u = (np.arange(k_u) + 0.5) / k_u * 2 * math.pi
        v = (np.arange(k_v) + 0.5) / k_v * 2 * math.pi
        U, V = np.meshgrid(u, v, indexing="ij")
        U, V = U.ravel(), V.ravel()
        nrm = np.stack([np.cos(V) * np.cos(U), np.cos(V) * np.sin(U), np.sin(V)], axis=1)
        ring = np.stack([np.cos(U), np.sin(U), np.zeros_like(U)], axis=1)
        return ring + r * nrm, nrm, 4 * math.pi**2 * r


class Room:
    """The inside of the box [-1, 1]^3: floor (z = -1) and walls/ceiling, seen from within.

    ``part(p)`` tells the floor (0) from the walls and ceiling (1), which are separate objects.
    """

    kind = "room"
    bound = math.inf

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d > 0, (1.0 - o) / d, np.where(d < 0, (-1.0 - o) / d, np.inf))
        s = t.min(axis=1)
        return np.where(s > EPS, s, np.inf)

    def normal(self, p: np.ndarray) -> np.ndarray:
        return -Box().normal(p)

    def part(self, p: np.ndarray) -> np.ndarray:
        """[M] 0 for points on the floor face, 1 elsewhere."""
        on_floor = np.abs(p[:, 2] + 1.0) <= np.abs(np.abs(p[:, :2]) - 1.0).min(axis=1)
        return np.where(on_floor, 0, 1)

    def sample(self, n: int) -> tuple[np.ndarray, np.ndarray, float]:
        p, nrm, area = Box().sample(n)
        return p, -nrm, area
