"""Synthetic scenes: generator -> raw files -> the toolkit's loaders -> the same cameras and truth.

Scenes are generated once per module at the ``tiny`` size (about a second each).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from benchmark.datasets import load_scene
from benchmark.datasets.synthetic import (
    DATASET_KEYS,
    build_world,
    generate,
    render,
)
from benchmark.datasets.synthetic.generate import rig_views
from benchmark.datasets.synthetic.world import rot

SIZE = "tiny"
SEQ = "synthetic-tiny"


class _Scenes(dict):
    """dataset -> scene dir, generated on first use (once per module)."""

    def __init__(self, root: Path):
        super().__init__()
        self.root = root

    def __missing__(self, dataset: str) -> Path:
        self[dataset] = generate(dataset, self.root / dataset / SEQ, seed=0, size=SIZE)
        return self[dataset]


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict[str, Path]:
    return _Scenes(tmp_path_factory.mktemp("synthetic"))


@pytest.fixture(scope="module")
def world():
    return build_world(0)


def _read_ids(scene_dir: Path, view_name: str) -> np.ndarray:
    man = json.loads((scene_dir / "synthetic" / "manifest.json").read_text())
    ids = cv2.imread(str(scene_dir / "synthetic" / man["instances"][view_name]), cv2.IMREAD_UNCHANGED)
    assert ids is not None and ids.dtype == np.uint16
    return ids


# -- cameras ------------------------------------------------------------------------------
@pytest.mark.parametrize("dataset", DATASET_KEYS)
def test_loader_cameras_equal_generator(scenes, dataset):
    scene = load_scene(dataset, scenes[dataset])
    assert scene.variant == "synthetic"
    rig = {v.view: v for v in rig_views(dataset, SIZE, 0)}
    views = scene.train + scene.test
    assert len(views) >= 6
    for v in views:
        r = rig[v.name]
        nat = v.native_camera
        assert nat is not None
        np.testing.assert_allclose(nat.w2c, r.camera.w2c, atol=1e-6, rtol=0)
        np.testing.assert_allclose(nat.K, r.camera.K, atol=1e-6, rtol=0)
        np.testing.assert_allclose(nat.radial, r.camera.radial, atol=1e-9)
        np.testing.assert_allclose(nat.tangential, r.camera.tangential, atol=1e-9)
        assert (nat.width, nat.height, nat.fisheye) == (r.camera.width, r.camera.height, r.camera.fisheye)
        # the training camera: same pose, pinhole, half resolution
        np.testing.assert_allclose(v.camera.w2c, r.camera.w2c, atol=1e-6, rtol=0)
        assert v.camera.is_pinhole and v.camera.width == r.camera.width // 2
        assert v.time == pytest.approx(r.time, abs=1e-9)


def test_time_rules(scenes):
    nerf = load_scene("hypernerf", scenes["hypernerf"])
    n_items = len(rig_views("hypernerf", SIZE))
    for v in nerf.train + nerf.test:
        assert v.time == pytest.approx(int(v.name) / (n_items - 1))
    mv = load_scene("neu3d", scenes["neu3d"])
    n = len({v.frame for v in mv.test})
    assert sorted({v.time for v in mv.train}) == pytest.approx([i / n for i in range(n)])


def test_splits_and_test_cameras(scenes):
    assert {v.name.split("_")[0] for v in load_scene("nerfds", scenes["nerfds"]).test} == {"right"}
    s = load_scene("hypernerf", scenes["hypernerf"])
    ids = [v.view for v in rig_views("hypernerf", SIZE)]
    assert [v.name for v in s.train] == ids[0::4] and [v.name for v in s.test] == ids[2::4]
    for d, cam in (("neu3d", "cam00"), ("immersive", "camera_0001"), ("technicolor", "cam00")):
        s = load_scene(d, scenes[d])
        assert {v.name.split("/")[0] for v in s.test} == {cam}
        assert cam not in {v.name.split("/")[0] for v in s.train}
    assert len({v.name.split("/")[0] for v in load_scene("neu3d", scenes["neu3d"]).train}) == 17
    assert len({v.name.split("/")[0] for v in load_scene("technicolor", scenes["technicolor"]).train}) == 15


# -- truth --------------------------------------------------------------------------------
def _segment_clear(world, name: str, t: float, eye: np.ndarray) -> bool:
    """No other object's bounding sphere crosses the segment eye -> centre of ``name``."""
    target = world.by_name(name)
    c = target.inside_point(t)
    seg = c - eye
    L = np.linalg.norm(seg)
    d = seg / L
    for o in world.objects:
        if o is target or not np.isfinite(o.shape.bound):
            continue
        _, oc, S = o.pose(t)
        rad = o.shape.bound * S.max()
        s = np.clip((oc - eye) @ d, 0.0, L)
        if np.linalg.norm(eye + s * d - oc) < rad:
            return False
    return True


@pytest.mark.parametrize("dataset", DATASET_KEYS)
def test_object_centre_projects_to_its_instance(scenes, world, dataset):
    scene = load_scene(dataset, scenes[dataset])
    checked = 0
    for v in scene.train + scene.test:
        ids = _read_ids(scenes[dataset], v.name)
        assert ids.shape == (v.camera.height, v.camera.width)
        for obj in world.objects[1:]:
            centre = obj.inside_point(v.time)
            (u, vv), z = (x[0] for x in v.camera.project(centre[None]))
            col, row = int(np.floor(u)), int(np.floor(vv))
            if z <= 0 or not (0 <= col < v.camera.width and 0 <= row < v.camera.height):
                continue
            if not _segment_clear(world, obj.name, v.time, v.camera.center):
                continue
            assert ids[row, col] == obj.id, f"{v.name}: centre of {obj.name} lands on id {ids[row, col]}"
            checked += 1
    assert checked >= 10


@pytest.mark.parametrize("dataset", ["hypernerf", "immersive"])
def test_native_lens_projection_hits_object(scenes, world, dataset):
    """Through the full native lens (distortion / fisheye): a rendered native image has the
    object at the pixel where Camera.project puts its centre."""
    scene = load_scene(dataset, scenes[dataset])
    checked = 0
    for v in scene.test[:2]:
        nat = v.native_camera
        _, _, ids = render(world, nat, v.time)
        for obj in world.objects[1:]:
            centre = obj.inside_point(v.time)
            (u, vv), z = (x[0] for x in nat.project(centre[None]))
            col, row = int(np.floor(u)), int(np.floor(vv))
            if z <= 0 or not (0 <= col < nat.width and 0 <= row < nat.height):
                continue
            if _segment_clear(world, obj.name, v.time, nat.center):
                assert ids[row, col] == obj.id
                checked += 1
    assert checked >= 2


@pytest.mark.parametrize("dataset", DATASET_KEYS)
def test_loader_images_match_truth_renders(scenes, world, dataset):
    """The images the loader serves look like the scene rendered at its camera (a rotated
    camera does clearly worse), so raw writing, lens and preparation are consistent."""
    scene = load_scene(dataset, scenes[dataset])
    blur = lambda x: cv2.GaussianBlur(x.astype(np.float32), (0, 0), 1.5)
    for v in (scene.test[0], scene.train[-1]):
        img = cv2.imread(str(v.image_path))[:, :, ::-1]
        errs = []
        for cam in (v.camera, _rotated(v.camera, 0.1)):
            ref, _, _ = render(world, cam.scaled(0.25), v.time)  # 4x4 supersampled
            ref = cv2.resize(ref, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
            errs.append(float(np.abs(blur(img) - blur(ref)).mean(axis=2)[3:-3, 5:-5].mean()))
        assert errs[0] < 5.0 and errs[0] < 0.7 * errs[1], (v.name, errs)


def _rotated(cam, angle):
    w2c = cam.w2c.copy()
    R = rot("y", angle)
    w2c[:3, :3] = R @ w2c[:3, :3]
    w2c[:3, 3] = R @ w2c[:3, 3]
    return dataclasses.replace(cam, w2c=w2c)


@pytest.mark.parametrize("dataset", DATASET_KEYS)
def test_gt_masks_and_manifest(scenes, world, dataset):
    root = scenes[dataset]
    scene = load_scene(dataset, root)
    assert len(scene.gt_masks) == len(scene.test) > 0
    man = json.loads((root / "synthetic" / "manifest.json").read_text())
    assert set(man["instances"]) == {v.name for v in scene.train + scene.test}
    assert {o["name"] for o in man["objects"] if o["of_interest"]} == {"ball", "ring", "blob"}
    interest = [o for o in man["objects"] if o["of_interest"]]
    any_fg = False
    for idx, (v, gt_path) in enumerate(zip(scene.test, scene.gt_masks)):
        assert gt_path.name == f"{idx:05d}.png"
        gt = cv2.imread(str(gt_path), cv2.IMREAD_UNCHANGED)
        assert gt.shape == (v.camera.height, v.camera.width) and set(np.unique(gt)) <= {0, 255}
        ids = _read_ids(root, v.name)
        np.testing.assert_array_equal(gt == 255, np.isin(ids, [o["id"] for o in interest]))
        union = np.zeros_like(gt, dtype=bool)
        for o in interest:
            m = cv2.imread(str(root / "gt_masks" / o["name"] / f"{idx:05d}.png"), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(m == 255, ids == o["id"])
            union |= m == 255
        np.testing.assert_array_equal(union, gt == 255)
        any_fg |= bool(gt.any())
    assert any_fg


def test_geometry_npz(scenes, world):
    root = scenes["nerfds"]
    scene = load_scene("nerfds", root)
    g = np.load(root / "synthetic" / "geometry.npz")
    N = len(g["means"])
    T = len(g["times"])
    assert 1000 < N <= 30000
    np.testing.assert_array_equal(g["times"], scene.times.astype(np.float32))
    for k, shape in (("means", (N, 3)), ("log_scales", (N, 3)), ("quats", (N, 4)), ("opacity_logits", (N,)),
                     ("colors", (N, 3)), ("object_ids", (N,)), ("d_xyz", (T, N, 3)), ("d_rot", (T, N, 4)),
                     ("d_scale", (T, N, 3))):
        assert g[k].shape == shape, k
        assert np.isfinite(g[k]).all(), k
    assert g["object_ids"].dtype == np.int32 and g["means"].dtype == np.float32
    assert set(np.unique(g["object_ids"])) == set(range(1, world.n_ids + 1))
    assert g["colors"].min() >= 0 and g["colors"].max() <= 1
    # deformed gaussians move with their object: the rolling ball's stay at a fixed distance
    # from its centre (under the surface: disks are sunk by a fitted inset of ~1-2 pixels,
    # a good part of the radius at the tiny size)
    ball = world.by_name("ball")
    sel = g["object_ids"] == ball.id
    r0 = None
    for ti, t in enumerate(g["times"]):
        _, c, S = ball.pose(float(t))
        r = np.linalg.norm(g["means"][sel] + g["d_xyz"][ti][sel] - c, axis=1)
        assert ((r > 0.1 * S[0]) & (r < S[0])).all()  # tiny: a 3-pixel ball sinks deep
        r0 = r if r0 is None else r0
        np.testing.assert_allclose(r, r0, atol=1e-5)
    # the deforming blob: local (undeformed) coordinates of its gaussians never change
    blob = world.by_name("blob")
    sel = g["object_ids"] == blob.id
    loc0 = None
    for ti, t in enumerate(g["times"]):
        R, c, S = blob.pose(float(t))
        local = ((g["means"][sel] + g["d_xyz"][ti][sel] - c) @ R) / S
        loc0 = local if loc0 is None else loc0
        np.testing.assert_allclose(local, loc0, atol=1e-4)
        assert (np.linalg.norm(local, axis=1) > 0.1).all() and (np.linalg.norm(local, axis=1) < 1.0).all()
        # rot_t = normalize(q) + d_rot is a unit quaternion
        q = g["quats"][sel] / np.linalg.norm(g["quats"][sel], axis=1, keepdims=True) + g["d_rot"][ti][sel]
        np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-5)
    static = g["object_ids"] == world.by_name("crate").id
    assert np.abs(g["d_xyz"][:, static]).max() == 0 and np.abs(g["d_rot"][:, static]).max() == 0


def _object_iou(g: dict, world, name: str, cam, ti: int) -> float:
    """IoU of one object's gaussians rendered alone (alpha >= 0.5) with its exact silhouette."""
    from benchmark.datasets.synthetic.fit import _alpha
    from benchmark.datasets.synthetic.world import World

    obj = world.by_name(name)
    sel = g["object_ids"] == obj.id
    sub = {k: (v[:, sel] if k in ("d_xyz", "d_rot", "d_scale") else v[sel]) for k, v in g.items()
           if k not in ("times",)}
    pred = _alpha(sub, cam, ti) >= 0.5
    truth = render(World([obj], world.seed), cam, cam.time)[2] > 0
    return (pred & truth).sum() / max((pred | truth).sum(), 1)


@pytest.mark.parametrize("dataset,floor", [("nerfds", 0.85), ("neu3d", 0.6)])  # tiny neu3d: 48x36 px
def test_geometry_silhouettes_match_on_test_views(scenes, world, dataset, floor):
    """Objects of interest rendered from geometry.npz alone match their exact outlines at the
    *test* cameras (the insets were fitted on training cameras only) far better than disks
    on the surface do."""
    from benchmark.datasets.synthetic.fit import pixel_footprint
    from benchmark.datasets.synthetic.gaussians import build_geometry

    root = scenes[dataset]
    scene = load_scene(dataset, root)
    man = json.loads((root / "synthetic" / "manifest.json").read_text())
    fit = man["geometry_fit"]["objects"]
    assert set(fit) == {o.name for o in world.objects if o.name != "room"}
    for rec in fit.values():
        assert 0.0 <= rec["inset_px"] <= 2.5 and rec["wrong_px"] <= rec["wrong_px_at_0"]
    with np.load(root / "synthetic" / "geometry.npz") as z:
        g = {k: z[k] for k in z.files}
    flat = build_geometry(world, scene.times, len(g["means"]), inset=0.0,
                          footprint=pixel_footprint([v.camera for v in scene.train]))
    fitted_iou, flat_iou = [], []
    for v in scene.test:
        ti = int(np.argmin(np.abs(g["times"] - v.time)))
        for name in man["objects_of_interest"]:
            fitted_iou.append(_object_iou(g, world, name, v.camera, ti))
            flat_iou.append(_object_iou(flat, world, name, v.camera, ti))
    assert np.mean(fitted_iou) > floor, np.mean(fitted_iou)
    assert np.mean(fitted_iou) > np.mean(flat_iou) + 0.1, (np.mean(fitted_iou), np.mean(flat_iou))


def test_pixel_footprint():
    from benchmark.datasets.synthetic.fit import pixel_footprint
    from trase.camera import Camera, intrinsics, look_at

    cams = [Camera(intrinsics(f, f, 32, 24), look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3)), 64, 48)
            for f in (50.0, 100.0, 200.0)]
    fp = pixel_footprint(cams)
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, -10.0, 0.0]])  # the last: behind
    np.testing.assert_allclose(fp(pts), [4.0 / 100.0, 6.0 / 100.0, 0.0], atol=1e-9)


# -- determinism, cache, embedded default ---------------------------------------------------
def _digest(root: Path, skip=("prepared.json",)) -> dict[str, str]:
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_dir() or p.name in skip:
            continue
        if p.suffix == ".mp4":
            cap = cv2.VideoCapture(str(p))
            h = hashlib.sha256()
            while True:
                ok, frame = cap.read()
                if not ok:
                    break
                h.update(frame.tobytes())
            cap.release()
            out[str(p.relative_to(root))] = "frames:" + h.hexdigest()
        else:
            out[str(p.relative_to(root))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.mark.parametrize("dataset", ["hypernerf", "neu3d"])
def test_deterministic(scenes, tmp_path, dataset):
    again = generate(dataset, tmp_path / SEQ, seed=0, size=SIZE)
    assert _digest(again) == _digest(scenes[dataset])


def test_seed_changes_scene(scenes, tmp_path):
    other = generate("hypernerf", tmp_path / SEQ, seed=1, size=SIZE)
    a, b = _digest(scenes["hypernerf"]), _digest(other)
    assert a.keys() == b.keys()
    assert a["rgb/2x/000000.png"] != b["rgb/2x/000000.png"]


@pytest.mark.parametrize("dataset", ["hypernerf", "technicolor"])
def test_initial_points_lie_on_surfaces(scenes, world, dataset):
    """points.npy (nerfies) / the prepared cloud (multi-view) are surface samples, in the
    loader's world: every point is on some surface of the scene at the first frame."""
    scene = load_scene(dataset, scenes[dataset])
    pts = scene.points
    assert 1000 < len(pts) <= 30000
    if dataset != "hypernerf":
        assert scene.point_colors is not None and len(scene.point_colors) == len(pts)
    # cast from the first camera's centre towards each point: the first hit is (about) the
    # point itself or something in front of it, never behind it
    cam = scene.train[0].camera
    d = pts - cam.center
    dist = np.linalg.norm(d, axis=1)
    hit, _, _ = world.cast(cam.center, d / dist[:, None], 0.0)
    # (float32 storage can push a point just off a surface that a ray only grazes)
    assert np.mean(hit <= dist + 1e-4) > 0.98
    assert np.mean(np.abs(hit - dist) < 1e-3) > 0.4  # a good share is directly visible
