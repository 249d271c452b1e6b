"""What the capture readers share: the holdout split, the frame-order time rule, the world
normalisation and COLMAP's sparse model (read with pycolmap, COLMAP's own bindings)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from benchmark.captures.options import CaptureOptions, holdout_every
from benchmark.datasets.errors import fail
from benchmark.datasets.scene import Scene, View


def order_times(names: list[str]) -> dict[str, tuple[int, float]]:
    """The frame-order rule: name -> (rank, rank / (n - 1)) with names sorted (one moving
    camera, frames named in capture order)."""
    ranked = sorted(names)
    last = max(len(ranked) - 1, 1)
    return {n: (i, i / last) for i, n in enumerate(ranked)}


def times_from_values(raw: dict[str, float], keep_unit: bool = False) -> dict[str, tuple[int, float]]:
    """name -> (rank among the distinct values, t in [0, 1]): (v - min) / (max - min), or the
    values themselves when ``keep_unit`` and they all lie in [0, 1] already."""
    lo, hi = min(raw.values()), max(raw.values())
    rank = {v: i for i, v in enumerate(sorted(set(raw.values())))}
    if keep_unit and lo >= 0 and hi <= 1:
        return {n: (rank[v], v) for n, v in raw.items()}
    return {n: (rank[v], (v - lo) / (hi - lo) if hi > lo else 0.0) for n, v in raw.items()}


def split_views(views: list[View], options: CaptureOptions, layout_test: set[str],
                notices: list[str]) -> tuple[list[View], list[View]]:
    """(train, test) by ``options.holdout``; every view trains by default."""
    if options.holdout == "none":
        return views, []
    if options.holdout == "layout":
        test = [v for v in views if v.name in layout_test]
        if not test:
            notices.append("holdout layout: the layout lists no test views; every view trains")
        return [v for v in views if v.name not in layout_test], test
    every = holdout_every(options.holdout)
    ordered = sorted(views, key=lambda v: (v.time, v.name))
    test_names = {v.name for i, v in enumerate(ordered) if i % every == 0}
    notices.append(f"holdout every:{every}: {len(test_names)} of {len(views)} views held out")
    return [v for v in views if v.name not in test_names], [v for v in views if v.name in test_names]


def normalization(points: np.ndarray) -> tuple[np.ndarray, float]:
    """(center, scale) putting 95% of the points in the unit ball: p -> (p - center) * scale."""
    center = np.median(points, axis=0)
    radius = float(np.percentile(np.linalg.norm(points - center, axis=1), 95)) if len(points) else 0.0
    return center, (1.0 / radius if radius > 1e-12 else 1.0)


def normalize_scene(scene: Scene, options: CaptureOptions, notices: list[str]) -> Scene:
    """``scene`` in the normalised world (cameras and points; images unchanged)."""
    if not options.normalize:
        return scene
    center, scale = normalization(scene.points)

    def move_camera(cam):
        if cam is None:
            return None
        R = cam.w2c[:3, :3]
        w2c = np.eye(4)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ ((cam.center - center) * scale)
        return dataclasses.replace(cam, w2c=w2c)

    def move(v: View) -> View:
        return dataclasses.replace(v, camera=move_camera(v.camera), native_camera=move_camera(v.native_camera))

    notices.append(f"world normalised: (p - {np.round(center, 4).tolist()}) x {scale:.4g}")
    scene.train = [move(v) for v in scene.train]
    scene.test = [move(v) for v in scene.test]
    scene.validation = [move(v) for v in scene.validation]
    scene.points = (scene.points - center) * scale
    scene.extras["normalization"] = {"center": center.tolist(), "scale": scale}
    return scene


def points_in_view(views: list[View], n: int = 20000, seed: int = 0) -> np.ndarray:
    """[n, 3] random points where the cameras look, for a capture with no points: a ball
    around the point nearest every optical axis (least squares), radius half the median camera
    distance to it, keeping points that at least half the cameras see. Deterministic."""
    cams = [v.camera for v in views]
    centers = np.stack([c.center for c in cams])
    axes = np.stack([c.c2w[:3, 2] for c in cams])  # optical axes (OpenCV: +z looks forward)
    A, b = np.zeros((3, 3)), np.zeros(3)
    for o, d in zip(centers, axes):
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ o
    target = np.linalg.lstsq(A, b, rcond=None)[0]
    radius = 0.5 * float(np.median(np.linalg.norm(centers - target, axis=1))) or 1.0
    rng = np.random.default_rng(seed)
    out: list[np.ndarray] = []
    while sum(len(o) for o in out) < n:
        d = rng.normal(size=(4 * n, 3))
        p = target + radius * d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0, 1, (4 * n, 1)) ** (1 / 3)
        seen = np.zeros(len(p), int)
        for c in cams:
            uv, z = c.project(p)
            seen += (z > 1e-6) & (uv[:, 0] >= 0) & (uv[:, 0] < c.width) & (uv[:, 1] >= 0) & (uv[:, 1] < c.height)
        out.append(p[seen * 2 >= len(cams)])
        if not out[-1].size and len(out) > 3:
            return p[:n]  # no common view (a poorly posed capture): the ball itself
    return np.concatenate(out)[:n]


def points_from_alpha(views: list[View], n: int = 20000, seed: int = 0, min_share: float = 0.5,
                      rounds: int = 20) -> tuple[np.ndarray, np.ndarray] | None:
    """([m, 3] points, [m, 3] colours in [0, 1]) inside the objects the images' alpha outlines,
    for a capture with no points whose images carry alpha (D-NeRF): random points where the
    cameras look (``points_in_view``), kept where they project inside the silhouette (alpha >=
    0.5) in at least ``min_share`` of the views that see them, coloured by the mean of those
    views' pixels. A soft visual hull: the object moves between the views' times, and the hull
    of every view would carve its moving parts away. None where the alpha outlines nothing (or
    too little to keep a tenth of ``n`` in ``rounds`` draws). Deterministic."""
    import cv2

    alphas, colours = [], []
    for v in views:  # one decode per image: its alpha and its straight (not composited) colour
        raw = cv2.imread(str(v.image_path), cv2.IMREAD_UNCHANGED)
        if raw is None or raw.ndim != 3 or raw.shape[2] != 4:
            return None
        top = 255.0 if raw.dtype == np.uint8 else 65535.0
        alphas.append(raw[:, :, 3] >= (top + 1) / 2)
        colours.append(raw[:, :, 2::-1].astype(np.float32) / np.float32(top))
    kept_p, kept_c = [], []
    rng = np.random.default_rng(seed)
    box = None  # after the first draw: the box of the points kept, where the next draws go
    for _ in range(rounds):
        if box is None:
            p = points_in_view(views, n, seed + 1)
        else:
            p = rng.uniform(box[0], box[1], (4 * n, 3))
        inside = np.zeros(len(p), int)
        seen = np.zeros(len(p), int)
        col = np.zeros((len(p), 3))
        for v, a, img in zip(views, alphas, colours):
            uv, z = v.camera.project(p)
            u, w = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
            ok = (z > 1e-6) & (u >= 0) & (u < a.shape[1]) & (w >= 0) & (w < a.shape[0])
            seen += ok
            hit = np.zeros(len(p), bool)
            hit[ok] = a[w[ok], u[ok]]
            inside += hit
            col[hit] += img[w[hit], u[hit]]
        keep = (seen > 0) & (inside >= min_share * np.maximum(seen, 1))
        kept_p.append(p[keep])
        kept_c.append(col[keep] / np.maximum(inside[keep], 1)[:, None])
        if sum(len(k) for k in kept_p) >= n:
            break
        if box is None and keep.sum() >= 8:
            lo, hi = p[keep].min(axis=0), p[keep].max(axis=0)
            pad = 0.1 * (hi - lo) + 1e-9
            box = (lo - pad, hi + pad)
    pts, cols = np.concatenate(kept_p)[:n], np.concatenate(kept_c)[:n]
    if len(pts) < max(n // 10, 1):
        return None
    return pts, np.clip(cols, 0.0, 1.0)


def read_colmap_model(sparse_dir: Path):
    """COLMAP's sparse model (cameras, images, points3D; .bin or .txt, with or without COLMAP
    4's rigs/frames) through pycolmap, or a one-line error naming the folder."""
    names = ("cameras", "images", "points3D")
    if not any((sparse_dir / f"{n}{ext}").is_file() for n in names for ext in (".bin", ".txt")):
        raise fail(sparse_dir, "no COLMAP model (cameras, images, points3D .bin or .txt)")
    for n in names:
        if not ((sparse_dir / f"{n}.bin").is_file() or (sparse_dir / f"{n}.txt").is_file()):
            raise fail(sparse_dir / f"{n}.bin", "missing COLMAP model file (.bin or .txt)")
    import pycolmap

    from benchmark.captures.colmap_binary import binary_model_problem

    problem = binary_model_problem(sparse_dir)
    if problem is not None:
        raise fail(*problem)
    try:
        return pycolmap.Reconstruction(str(sparse_dir))
    except (ValueError, RuntimeError, OSError, MemoryError) as exc:  # a truncated count: bad_alloc
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise fail(sparse_dir, f"cannot read the COLMAP model ({reason})") from None


def colmap_points(model, where: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(points [N, 3] float64, colours [N, 3] in [0, 1]) of a COLMAP model."""
    pts = [(p.xyz, p.color) for p in model.points3D.values()]
    if not pts:
        raise fail(where, "the COLMAP model has no 3D points")
    xyz = np.array([p[0] for p in pts], np.float64)
    rgb = np.array([p[1] for p in pts], np.float64) / 255.0
    if not np.isfinite(xyz).all():
        raise fail(where, "COLMAP points contain NaN or Inf")
    return xyz, rgb


def closest_copy(wanted: int, have: dict[int, Path], missing: Path, what: str) -> tuple[int, Path]:
    """(scale, folder) of the pre-scaled copy to read for images at 1/``wanted``: the copy at
    that scale, else the coarsest finer one whose scale divides it (the rest is scaled on the
    fly, benchmark.captures.scaling); ``have``: scale -> folder of the copies present."""
    if wanted in have:
        return wanted, have[wanted]
    finer = [k for k in have if wanted % k == 0]
    if not finer:
        listed = ", ".join(have[k].name for k in sorted(have)) or "none"
        raise fail(missing, f"missing {what} (found: {listed}), and none finer to scale from")
    k = max(finer)
    return k, have[k]


def check_views(views: list[View], where: Path) -> None:
    if not views:
        raise fail(where, "no views to train on")
    names = [v.name for v in views]
    if len(set(names)) != len(names):
        raise fail(where, "two views have the same name")


@dataclasses.dataclass(frozen=True)
class CaptureLayout:
    """One capture layout: what it looks like (for errors), how to spot it, how to read it."""

    signature: str
    detect: object  # (scene_dir: Path) -> bool
    load: object  # (scene_dir: Path, options: CaptureOptions) -> Scene


def capture_scene(scene_dir: Path, views: list[View], options: CaptureOptions, layout_test: set[str],
                  points: np.ndarray, colors: np.ndarray | None, notices: list[str], extras: dict) -> Scene:
    """The ``Scene`` of a capture: views split by the holdout rule, no ground truth."""
    from trase.reconstruct import is_motionless

    check_views(views, scene_dir)
    train, test = split_views(views, options, layout_test, notices)
    if is_motionless(train):
        notices.append(f"every training view at one time ({train[0].camera.time:g}): a motionless capture, "
                       "reconstructed as plain 3DGS (no deformation network)")
    return Scene(dataset="capture", sequence=scene_dir.resolve().name, root=scene_dir, train=train, test=test,
                 points=points, point_colors=colors, variant="real",
                 extras={**extras, "notices": notices, "capture": options.to_dict()})
