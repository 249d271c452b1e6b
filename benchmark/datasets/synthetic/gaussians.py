"""The scene as gaussians with a tabulated deformation (``synthetic/geometry.npz``).

Each surface is covered by flattened disks: one gaussian per surface sample, its two tangent
axes as wide as the sample spacing and a thin normal axis. Canonical = the scene at the first
tabulated time. For every tabulated time the object's affine map A_t (see ``world.py``) moves
each gaussian: mean -> A_t(mean); the disk's tangent axes are mapped by the linear part and the
frame is re-orthonormalised around the transformed normal, so rotation and scale offsets follow
the surface exactly for rigid motion and closely for the per-axis (non-rigid) stretching.

Semantics are Deformable-3DGS's: means_t = means + d_xyz, rot_t = normalize(quat) + d_rot,
scales_t = exp(log_scales) + d_scale.

Silhouettes: the rasterizer widens every splat by a fixed 0.3 px^2 low-pass (3DGS) and many
disks overlap along grazing rays, so the alpha >= 0.5 outline of a surface made of disks lies
about a pixel *outside* the true outline, whatever the disks' world size. Disks are therefore
sunk below the surface along their normal by an inset measured in *pixels* of the rig's
training cameras (``footprint``: metres per pixel at a point), chosen per object by
``fit.calibrate_insets`` against exact ray-cast silhouettes of the training cameras.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .shapes import Room
from .world import World

DISK_SIGMA = 0.5  # tangential std of a disk, in sample spacings
INSET = 2.0  # without a pixel footprint: disks sit this many sigmas below the surface


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """[N, 3, 3] rotation matrices -> [N, 4] unit quaternions (w, x, y, z), w >= 0."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
    q = np.concatenate([q[:, 3:], q[:, :3]], axis=1)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def _frames(normals: np.ndarray, tangents: np.ndarray | None = None) -> np.ndarray:
    """[N, 3, 3] rotations whose columns are (t1, t2, n) for unit normals [N, 3]."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    if tangents is None:
        helper = np.where(np.abs(n[:, 2:3]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
        tangents = np.cross(helper, n)
    t1 = tangents - np.einsum("ij,ij->i", tangents, n)[:, None] * n
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    return np.stack([t1, t2, n], axis=2)


def _place(pose, p_local: np.ndarray, n_local: np.ndarray):
    """Local points/normals -> world points [N, 3], world unit normals [N, 3], linear map [3, 3]."""
    R, c, S = pose
    A = R * S[None, :]  # R @ diag(S)
    pts = p_local @ A.T + c
    nrm = (n_local / S) @ R.T
    return pts, nrm / np.linalg.norm(nrm, axis=1, keepdims=True), A


def _budget(world: World, total: int) -> dict[int, int]:
    """Gaussians per object: the room takes ~40%, objects share the rest by area (>= 500 each)."""
    room_share = int(total * 0.4)
    areas = {}
    for k, obj in enumerate(world.objects):
        if isinstance(obj.shape, Room):
            continue
        _, _, S = obj.pose(0.0)
        _, _, a = obj.shape.sample(64)
        areas[k] = a * float(np.prod(S)) ** (2.0 / 3.0)
    rest = total - room_share
    tot_a = sum(areas.values())
    out = {k: max(500, int(rest * a / tot_a)) for k, a in areas.items()}
    for k, obj in enumerate(world.objects):
        if isinstance(obj.shape, Room):
            out[k] = room_share
    return out


def _room_samples(obj, n: int):
    """Room faces sampled on world-square grids (floor and back wall denser), local coords."""
    _, _, S = obj.pose(0.0)
    faces = []  # (axis, sign, weight)
    for axis in range(3):
        for sign in (-1.0, 1.0):
            w = 1.0
            if axis == 2 and sign < 0:
                w = 3.0  # floor
            if axis == 1 and sign > 0:
                w = 2.0  # back wall
            faces.append((axis, sign, w))
    areas = []
    for axis, sign, w in faces:
        a, b = [x for x in range(3) if x != axis]
        areas.append(4.0 * S[a] * S[b] * w)
    density = n / sum(areas)  # samples per weighted square metre
    pts, nrm, spacing = [], [], []
    for (axis, sign, w), area in zip(faces, areas):
        a, b = [x for x in range(3) if x != axis]
        step = math.sqrt(1.0 / (density * w))  # metres between samples on this face
        ka = max(2, round(2 * S[a] / step))
        kb = max(2, round(2 * S[b] / step))
        ga = (np.arange(ka) + 0.5) / ka * 2 - 1
        gb = (np.arange(kb) + 0.5) / kb * 2 - 1
        A, B = np.meshgrid(ga, gb, indexing="ij")
        p = np.zeros((A.size, 3))
        p[:, axis] = sign
        p[:, a] = A.ravel()
        p[:, b] = B.ravel()
        nn = np.zeros_like(p)
        nn[:, axis] = -sign
        pts.append(p)
        nrm.append(nn)
        spacing.append(np.full(A.size, math.sqrt((2 * S[a] / ka) * (2 * S[b] / kb))))
    return np.concatenate(pts), np.concatenate(nrm), np.concatenate(spacing)


def build_geometry(world: World, times: np.ndarray, budget: int, inset: float | dict[str, float] = INSET,
                   footprint: Callable[[np.ndarray], np.ndarray] | None = None,
                   only: str | None = None) -> dict[str, np.ndarray]:
    """Gaussians covering every surface + their per-time offsets (the arrays of ``trase.checkpoint.TABULATED_KEYS``).

    ``inset``: how deep each object's disks sink below its surface (one value, or one per
    object name; missing names sink 0): in pixels of ``footprint`` (points [N, 3] -> metres per
    pixel [N]) when given, else in disk sigmas. ``inset=0`` puts the means exactly on the
    surfaces (used for SfM-like point clouds). The room never sinks. ``only``: build just
    the object of that name (same gaussians as in the full build; for calibration)."""
    times = np.asarray(times, dtype=np.float64)
    t0 = float(times[0])
    per_obj = _budget(world, budget)
    chunks = []
    for k, obj in enumerate(world.objects):
        if only is not None and obj.name != only:
            continue
        if isinstance(obj.shape, Room):
            p_l, n_l, spacing = _room_samples(obj, per_obj[k])
        else:
            p_l, n_l, area = obj.shape.sample(per_obj[k])
            _, _, S = obj.pose(t0)
            # world area per sample: |det A| * |A^-T n| times the local area per sample
            stretch = np.prod(S) * np.linalg.norm(n_l / S, axis=1)
            spacing = np.sqrt(area / len(p_l) * stretch)
        colors = obj.color(p_l, n_l)
        ids = obj.ids_of(p_l)
        pts0, nrm0, A0 = _place(obj.pose(t0), p_l, n_l)
        sig = DISK_SIGMA * spacing
        depth = inset.get(obj.name, 0.0) if isinstance(inset, dict) else inset
        if depth and not isinstance(obj.shape, Room):
            # sink each disk along its normal so that the rendered outline (alpha >= 0.5)
            # matches the true one (see the module docstring)
            unit = footprint(pts0) if footprint is not None else sig  # metres per inset unit [N]
            pts0 = pts0 - (float(depth) * unit)[:, None] * nrm0
            p_l = (pts0 - obj.pose(t0)[1]) @ np.linalg.inv(A0).T
        frame0 = _frames(nrm0)
        # tangents in local coordinates, so the same material directions move with the surface
        t_local = np.einsum("ij,njk->nik", np.linalg.inv(A0), frame0[:, :, :1])[:, :, 0]
        scales0 = np.stack([sig, sig, np.maximum(0.08 * sig, 1e-4)], axis=1)
        q0 = rotmat_to_quat(frame0)
        d_xyz, d_rot, d_scale = [], [], []
        for t in times if obj.motion != "static" else []:
            pts, nrm, A = _place(obj.pose(float(t)), p_l, n_l)
            tan = t_local @ A.T
            fr = _frames(nrm, tan)
            # tangent stretch: how much the linear map lengthens each disk axis
            stretch1 = np.linalg.norm(np.einsum("ij,njk->nik", A @ np.linalg.inv(A0), frame0[:, :, 0:1])[:, :, 0], axis=1)
            stretch2 = np.linalg.norm(np.einsum("ij,njk->nik", A @ np.linalg.inv(A0), frame0[:, :, 1:2])[:, :, 0], axis=1)
            q = rotmat_to_quat(fr)
            q *= np.where(np.einsum("ij,ij->i", q, q0) < 0, -1.0, 1.0)[:, None]
            sc = scales0 * np.stack([stretch1, stretch2, np.ones_like(stretch1)], axis=1)
            d_xyz.append(pts - pts0)
            d_rot.append(q - q0)
            d_scale.append(sc - scales0)
        if obj.motion == "static":  # exactly zero offsets
            d_xyz = [np.zeros_like(pts0)] * len(times)
            d_rot = [np.zeros_like(q0)] * len(times)
            d_scale = [np.zeros_like(scales0)] * len(times)
        chunks.append({
            "means": pts0, "log_scales": np.log(scales0), "quats": q0,
            "opacity_logits": np.full(len(p_l), 4.0), "colors": colors, "object_ids": ids,
            "d_xyz": np.stack(d_xyz), "d_rot": np.stack(d_rot), "d_scale": np.stack(d_scale),
        })
    out = {}
    for key in ("means", "log_scales", "quats", "opacity_logits", "colors"):
        out[key] = np.concatenate([c[key] for c in chunks]).astype(np.float32)
    out["object_ids"] = np.concatenate([c["object_ids"] for c in chunks]).astype(np.int32)
    for key in ("d_xyz", "d_rot", "d_scale"):
        out[key] = np.concatenate([c[key] for c in chunks], axis=1).astype(np.float32)
    out["times"] = times.astype(np.float32)
    return out
