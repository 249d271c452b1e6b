"""The procedural dynamic scene: a textured room and moving / deforming objects, ray cast exactly.

World axes: z up, the floor is z = 0, the cameras look roughly along +y towards the origin.
Each object is a canonical shape (``shapes.py``) placed by a per-time affine map

    x_world = R(t) @ (S(t) * x_local) + c(t)

(rotation R, translation c, per-axis scale S; a time-varying S is the non-rigid part). A world
ray o + s d maps to the local ray o_l = (R^T (o - c)) / S, d_l = (R^T d) / S, so the distance s
is shared and depth comparisons between objects are exact. Colour is a function of the local
surface point and local normal only (texture with baked shading), so it moves with the surface
and the ground-truth gaussians can carry it exactly.

The layout is fixed (so "a small ball next to a crate" always holds); the seed changes colours,
texture offsets and motion phases. ``span`` is the part of the motion a sequence covers: the
pose functions are written for span 1 (the ``hard`` scenes: every object's whole path within
the sequence), and a sequence time t in [0, 1] is motion time span * t, so a benchmark-like
scene (``rigs.py``) moves its objects as far per frame as the real benchmark's content does.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from .shapes import Box, Cylinder, Room, Sphere, Torus

Pose = tuple[np.ndarray, np.ndarray, np.ndarray]  # R [3, 3], c [3], S [3]


def rot(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=np.float64)
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=np.float64)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float64)


@dataclasses.dataclass
class SceneObject:
    id: int  # instance id in the id maps (1..K); a room spans id (floor) and id + 1 (walls)
    name: str
    shape: object  # one of shapes.*
    motion: str  # static | rigid | deforming (for the manifest)
    of_interest: bool
    pose: Callable[[float], Pose]
    albedo: Callable[[np.ndarray], np.ndarray]  # local points [M, 3] -> rgb [M, 3] in [0, 1]
    light: np.ndarray  # unit light direction in the local frame (baked shading)

    def color(self, p_local: np.ndarray, n_local: np.ndarray) -> np.ndarray:
        """[M, 3] shaded colour in [0, 1] of local surface points with local normals."""
        lam = np.clip(n_local @ self.light, 0.0, 1.0)
        return np.clip(self.albedo(p_local) * (0.55 + 0.45 * lam)[:, None], 0.0, 1.0)

    def inside_point(self, t: float) -> np.ndarray:
        """[3] a world point inside the solid at time t (its centre; the tube for a torus)."""
        R, c, S = self.pose(t)
        local = np.array([1.0, 0.0, 0.0]) if isinstance(self.shape, Torus) else np.zeros(3)
        return R @ (S * local) + c

    def ids_of(self, p_local: np.ndarray) -> np.ndarray:
        if isinstance(self.shape, Room):
            return self.id + self.shape.part(p_local)
        return np.full(len(p_local), self.id)


# -- textures -----------------------------------------------------------------------------
def checker(c1, c2, freq: float, offset) -> Callable[[np.ndarray], np.ndarray]:
    c1, c2, offset = np.asarray(c1, float), np.asarray(c2, float), np.asarray(offset, float)

    def f(p: np.ndarray) -> np.ndarray:
        k = np.floor((p + offset) * freq).sum(axis=1).astype(np.int64) % 2
        return np.where(k[:, None] == 0, c1, c2)

    return f


def stripes(c1, c2, freq: float, axis: int, offset: float) -> Callable[[np.ndarray], np.ndarray]:
    c1, c2 = np.asarray(c1, float), np.asarray(c2, float)

    def f(p: np.ndarray) -> np.ndarray:
        w = 0.5 + 0.5 * np.sin((p[:, axis] + offset) * freq * 2 * math.pi)
        return c1 * w[:, None] + c2 * (1 - w[:, None])

    return f


def bands(base, accent, freq: float) -> Callable[[np.ndarray], np.ndarray]:
    """Latitude bands plus meridians: shows rotation of round objects."""
    base, accent = np.asarray(base, float), np.asarray(accent, float)

    def f(p: np.ndarray) -> np.ndarray:
        ang = np.arctan2(p[:, 1], p[:, 0])
        m = (np.floor(ang / (2 * math.pi) * freq * 2) + np.floor(p[:, 2] * freq)).astype(np.int64) % 2
        return np.where(m[:, None] == 0, base, accent)

    return f


def room_texture(floor1, floor2, wall1, wall2, size, offset) -> Callable[[np.ndarray], np.ndarray]:
    """Floor: 0.4 m checker tiles; walls and ceiling: bricks (world-sized through ``size``)."""
    f1, f2, w1, w2 = (np.asarray(c, float) for c in (floor1, floor2, wall1, wall2))
    size, offset = np.asarray(size, float), np.asarray(offset, float)

    def f(p: np.ndarray) -> np.ndarray:
        q = p * size + offset  # metres
        on_floor = Room().part(p) == 0
        tile = (np.floor(q[:, 0] / 0.4) + np.floor(q[:, 1] / 0.4)).astype(np.int64) % 2
        floor = np.where(tile[:, None] == 0, f1, f2)
        row = np.floor(q[:, 2] / 0.25)
        shift = 0.5 * (row.astype(np.int64) % 2)
        along = q[:, 0] + q[:, 1]
        brick = (np.abs(((along / 0.5 + shift) % 1.0) - 0.5) > 0.45) | (np.abs(((q[:, 2] / 0.25) % 1.0) - 0.5) > 0.42)
        shade = 0.85 + 0.15 * np.sin(row * 1.7 + np.floor(along / 0.5 + shift) * 2.3)
        wall = np.where(brick[:, None], w2, w1 * shade[:, None])
        return np.where(on_floor[:, None], floor, wall)

    return f


# -- the scene ----------------------------------------------------------------------------
@dataclasses.dataclass
class World:
    objects: list[SceneObject]
    seed: int
    span: float = 1.0  # part of the motion the sequence covers (see the module docs)

    @property
    def n_ids(self) -> int:
        return max(o.id + (1 if isinstance(o.shape, Room) else 0) for o in self.objects)

    def object_table(self) -> list[dict]:
        """[{id, name, kind, motion, of_interest}] for every instance id (room split in two)."""
        rows = []
        for o in self.objects:
            if isinstance(o.shape, Room):
                rows.append({"id": o.id, "name": "floor", "kind": "room-floor", "motion": "static", "of_interest": False})
                rows.append({"id": o.id + 1, "name": "walls", "kind": "room-walls", "motion": "static", "of_interest": False})
            else:
                rows.append({"id": o.id, "name": o.name, "kind": o.shape.kind, "motion": o.motion, "of_interest": o.of_interest})
        return rows

    def of_interest(self) -> list[SceneObject]:
        return [o for o in self.objects if o.of_interest]

    def by_name(self, name: str) -> SceneObject:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(name)

    def centre(self, name: str, t: float) -> np.ndarray:
        """[3] world centre of an object at time t."""
        return self.by_name(name).pose(t)[1].copy()

    def cast(self, origin: np.ndarray, dirs: np.ndarray, t: float, valid: np.ndarray | None = None):
        """Trace rays from one origin [3] along unit world dirs [M, 3] at time t.

        Returns (dist [M] (inf = nothing hit), ids [M] uint16 (0 = nothing), rgb [M, 3] float).
        """
        M = len(dirs)
        best = np.full(M, np.inf)
        owner = np.full(M, -1)
        if valid is None:
            valid = np.ones(M, dtype=bool)
        locals_ = []
        for k, obj in enumerate(self.objects):
            R, c, S = obj.pose(t)
            o_l = (R.T @ (origin - c)) / S
            sel = np.nonzero(valid)[0]
            if math.isfinite(obj.shape.bound):
                # cull with the bounding sphere of the placed shape (world radius)
                rad = obj.shape.bound * S.max()
                oc = origin - c
                b = dirs[sel] @ oc
                disc = b * b - (oc @ oc - rad * rad)
                sel = sel[(disc >= 0) & (-b + np.sqrt(np.maximum(disc, 0)) > 0)]
            d_l = (dirs[sel] @ R) / S  # == (R^T d) / S per row
            k_norm = np.linalg.norm(d_l, axis=1)
            s_l = obj.shape.intersect(np.broadcast_to(o_l, d_l.shape), d_l / k_norm[:, None])
            s = s_l / k_norm
            win = s < best[sel]
            best[sel[win]] = s[win]
            owner[sel[win]] = k
            locals_.append((R, c, S, o_l))
        ids = np.zeros(M, dtype=np.uint16)
        rgb = np.zeros((M, 3))
        for k, obj in enumerate(self.objects):
            hit = np.nonzero(owner == k)[0]
            if hit.size == 0:
                continue
            R, c, S, o_l = locals_[k]
            d_l = (dirs[hit] @ R) / S
            p_l = o_l + best[hit, None] * d_l
            n_l = obj.shape.normal(p_l)
            ids[hit] = obj.ids_of(p_l)
            rgb[hit] = obj.color(p_l, n_l)
        return best, ids, rgb


def build_world(seed: int = 0, span: float = 1.0) -> World:
    """The scene for a seed (layout fixed; colours, texture offsets and motion phases vary).

    ``span`` in (0, 1]: the part of every object's motion the sequence time [0, 1] covers.
    """
    if not 0.0 < span <= 1.0:
        raise ValueError(f"motion span must be in (0, 1], got {span}")
    rng = np.random.default_rng(seed)
    poses = _motions(rng.uniform(0, 2 * math.pi, 4), span)  # the phases: the seed's first draws
    return World(_objects(rng, poses), seed, span)


def _static(c, S, R=None) -> Callable[[float], Pose]:
    """The pose of an object that does not move: rotation R (default identity), centre c, scale S."""
    R = np.eye(3) if R is None else R
    c, S = np.asarray(c, float), np.asarray(S, float)
    return lambda t: (R, c, S)


def _motions(ph: np.ndarray, span: float) -> dict[str, Callable[[float], Pose]]:
    """The moving objects' poses (written for span 1) with the seed's 4 phases ``ph``, in
    sequence time: motion time is span * t."""
    I3 = np.eye(3)
    ones = np.ones(3)

    def ball_pose(t):
        x = -0.30 - 0.09 * math.sin(2 * math.pi * t + ph[0])
        r = 0.12
        return rot("y", x / r), np.array([x, 0.22, r]), r * ones

    def ring_pose(t):
        R = rot("z", math.pi * t + ph[1]) @ rot("x", 1.1)
        return R, np.array([-0.85, 0.75, 0.62 + 0.12 * math.sin(2 * math.pi * t)]), 0.28 * ones

    def blob_pose(t):
        w = 2 * math.pi * t + ph[2]
        S = 0.3 * np.array([1 + 0.25 * math.sin(w), 1 - 0.2 * math.sin(w), 1 + 0.2 * math.sin(2 * w)])
        return rot("z", 0.8 * t), np.array([1.15, -0.15, S[2]]), S

    def pillar_pose(t):
        return I3, np.array([-2.7 + 5.4 * t, -0.95, 0.62]), np.array([0.14, 0.14, 0.62])

    def cube_pose(t):
        R = rot("z", 4 * math.pi * t + ph[3]) @ rot("x", 0.5)
        c = np.array([3.2 - 6.4 * t, 1.3, 1.15 + 0.2 * math.sin(6 * math.pi * t)])
        return R, c, 0.13 * ones

    def spanned(pose):
        return pose if span == 1.0 else (lambda t: pose(span * t))

    return {"ball": spanned(ball_pose), "ring": spanned(ring_pose), "blob": spanned(blob_pose),
            "pillar": spanned(pillar_pose), "cube": spanned(cube_pose)}


def _objects(rng: np.random.Generator, poses: dict[str, Callable[[float], Pose]]) -> list[SceneObject]:
    """The fixed layout: room, crate, ball, ring, blob, pillar, cube, can. ``rng`` draws their
    colours, texture offsets and light directions in exactly this order (argument by argument),
    which the generated scenes' bytes depend on."""

    def jitter(c, amount=0.12):
        return np.clip(np.asarray(c, float) + rng.uniform(-amount, amount, 3), 0.05, 0.95)

    def light():
        v = np.array([0.4, -0.5, 0.75]) + rng.uniform(-0.15, 0.15, 3)
        return v / np.linalg.norm(v)

    return [
        SceneObject(1, "room", Room(), "static", False,
                    _static([0.0, -1.0, 1.5], [3.5, 4.0, 1.5]),
                    room_texture(jitter([0.75, 0.72, 0.65]), jitter([0.35, 0.33, 0.3]),
                                 jitter([0.7, 0.45, 0.35]), jitter([0.85, 0.85, 0.8], 0.05),
                                 [3.5, 4.0, 1.5], rng.uniform(0, 1, 3)),
                    np.array([0.3, 0.5, 0.81])),
        SceneObject(3, "crate", Box(), "static", False,
                    _static([0.55, 0.55, 0.35], [0.42, 0.42, 0.35], rot("z", 0.35)),
                    stripes(jitter([0.65, 0.45, 0.25]), jitter([0.45, 0.28, 0.12]), 3.0, 0, rng.uniform()),
                    light()),
        SceneObject(4, "ball", Sphere(), "rigid", True, poses["ball"],
                    bands(jitter([0.9, 0.2, 0.2]), jitter([0.95, 0.9, 0.3]), 3.0), light()),
        SceneObject(5, "ring", Torus(0.3), "rigid", True, poses["ring"],
                    bands(jitter([0.2, 0.4, 0.9]), jitter([0.85, 0.85, 0.9]), 4.0), light()),
        SceneObject(6, "blob", Sphere(), "deforming", True, poses["blob"],
                    checker(jitter([0.25, 0.8, 0.3]), jitter([0.1, 0.45, 0.15]), 3.0, rng.uniform(0, 1, 3)),
                    light()),
        SceneObject(7, "pillar", Cylinder(), "rigid", False, poses["pillar"],
                    stripes(jitter([0.8, 0.8, 0.8]), jitter([0.3, 0.3, 0.5]), 4.0, 2, rng.uniform()),
                    light()),
        SceneObject(8, "cube", Box(), "rigid", False, poses["cube"],
                    checker(jitter([0.9, 0.6, 0.1]), jitter([0.3, 0.1, 0.5]), 2.0, rng.uniform(0, 1, 3)),
                    light()),
        SceneObject(9, "can", Cylinder(), "static", False,
                    _static([-1.45, -0.15, 0.25], [0.16, 0.16, 0.25]),
                    bands(jitter([0.6, 0.2, 0.7]), jitter([0.9, 0.9, 0.9]), 2.0), light()),
    ]


def render(world: World, cam, t: float, rays=None):
    """Ray cast one image of ``cam`` (a ``trase.camera.Camera``, any lens) at time t.

    ``rays``: the output of ``rays.camera_rays(cam)``, to reuse across the frames of a fixed
    camera. Returns (rgb uint8 [H, W, 3], depth float32 [H, W] camera-space z (0 = nothing),
    ids uint16 [H, W] instance ids (0 = nothing)).
    """
    from .rays import camera_rays

    origin, dirs, zc, ok = rays if rays is not None else camera_rays(cam)
    dist, ids, rgb = world.cast(origin, dirs, t, ok)
    hit = np.isfinite(dist)
    depth = np.where(hit, dist * zc, 0.0)
    H, W = cam.height, cam.width
    img = np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8).reshape(H, W, 3)
    return img, depth.astype(np.float32).reshape(H, W), ids.reshape(H, W)
