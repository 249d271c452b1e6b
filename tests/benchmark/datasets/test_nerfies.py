import json

import cv2
import numpy as np
import pytest
from fixture_writers import nerfies_camera_dict, write_nerfies

from benchmark.datasets import DatasetError, load_scene
from benchmark.datasets.nerfies import read_camera
from trase.camera import look_at


def test_read_camera_projection_matches_opencv(tmp_path):
    w2c = look_at([0.5, -3.0, 0.4], [0, 0, 0])
    d = nerfies_camera_dict(w2c, f=40.0, pp=(16.5, 11.0), radial=(0.05, -0.01, 0.002),
                            tangential=(0.003, -0.002))
    p = tmp_path / "cam.json"
    p.write_text(json.dumps(d))
    cam = read_camera(p)
    pts = np.random.default_rng(1).uniform(-0.5, 0.5, size=(20, 3))
    uv, depth = cam.project(pts)
    R, t = w2c[:3, :3], w2c[:3, 3]
    K = np.array([[40.0, 0, 16.5], [0, 40.0, 11.0], [0, 0, 1]])
    dist = np.array([0.05, -0.01, 0.003, -0.002, 0.002])  # OpenCV order k1 k2 p1 p2 k3
    ref, _ = cv2.projectPoints(pts, cv2.Rodrigues(R)[0], t, K, dist)
    np.testing.assert_allclose(uv, ref[:, 0], atol=1e-9)
    np.testing.assert_allclose(depth, (pts @ R.T + t)[:, 2], atol=1e-12)


def test_read_camera_skew_aspect_by_hand_and_old_tangential_key(tmp_path):
    w2c = look_at([0.0, -2.0, 0.0], [0, 0, 0])
    d = nerfies_camera_dict(w2c, f=50.0, pp=(10.0, 8.0), skew=0.7, aspect=1.1,
                            radial=(0.1, 0.0, 0.0), tangential=(0.0, 0.01), tangential_key="tangential")
    p = tmp_path / "cam.json"
    p.write_text(json.dumps(d))
    cam = read_camera(p)
    X = np.array([[0.3, 0.2, 0.1]])
    pc = w2c[:3, :3] @ X[0] + w2c[:3, 3]
    x, y = pc[0] / pc[2], pc[1] / pc[2]
    r2 = x * x + y * y
    rad = 1 + 0.1 * r2
    p1, p2 = 0.0, 0.01
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    u = 50.0 * xd + 0.7 * yd + 10.0
    v = 50.0 * 1.1 * yd + 8.0
    uv, _ = cam.project(X)
    np.testing.assert_allclose(uv[0], [u, v], atol=1e-10)
    assert cam.tangential == (0.0, 0.01)


def test_hypernerf_split_times_and_views(tmp_path):
    root = write_nerfies(tmp_path / "hypernerf" / "americano", n_items=12)
    scene = load_scene("hypernerf", root)
    ids = json.loads((root / "dataset.json").read_text())["ids"]
    assert [v.name for v in scene.train] == ids[0::4]
    assert [v.name for v in scene.test] == ids[2::4]
    assert scene.test[0].time == pytest.approx(2 / 11)  # time_id / max over all ids
    v = scene.test[0]
    assert (v.camera.width, v.camera.height) == (16, 12) and v.camera.is_pinhole
    assert v.camera.cx == pytest.approx(16.5 / 2) and v.camera.fx == pytest.approx(20.0)
    assert not v.native_camera.is_pinhole and v.native_camera.width == 32
    assert len(scene.gt_masks) == len(scene.test) == 3
    assert scene.extras["distortion_dropped_px"] > 0
    # scene.json normalisation: (p - center) * scale
    raw = np.load(root / "points.npy")
    np.testing.assert_allclose(scene.points, (raw - [0.1, 0.2, 0.3]) * 0.5)
    c_raw = np.array(json.loads((root / "camera" / f"{v.name}.json").read_text())["position"])
    np.testing.assert_allclose(v.camera.center, (c_raw - [0.1, 0.2, 0.3]) * 0.5, atol=1e-12)


def test_normalised_world_projects_points_to_same_pixels(tmp_path):
    root = write_nerfies(tmp_path / "hypernerf" / "americano", n_items=4, gt=False)
    scene = load_scene("hypernerf", root)
    v = scene.train[0]
    raw_cam = read_camera(root / "camera" / f"{v.name}.json")
    X = np.array([[0.2, 0.1, -0.1]])
    uv_raw, _ = raw_cam.project(X)
    uv_norm, _ = v.native_camera.project((X - [0.1, 0.2, 0.3]) * 0.5)
    np.testing.assert_allclose(uv_raw, uv_norm, atol=1e-9)


def test_nerfds_split_from_registry_not_folder_name(tmp_path):
    # folder name says nothing about NeRF-DS; the registry key decides the split
    root = write_nerfies(tmp_path / "renamed_scene", n_items=8, two_cameras=True)
    scene = load_scene("nerfds", root, sequence="cup_novel_view")
    assert all(v.name.startswith("left") for v in scene.train)
    assert all(v.name.startswith("right") for v in scene.test)
    assert scene.sequence == "cup_novel_view"
    assert scene.test[-1].time == pytest.approx(1.0)


def test_warp_id_when_time_id_missing(tmp_path):
    root = write_nerfies(tmp_path / "x", n_items=8, time_key="warp_id", gt=False)
    scene = load_scene("hypernerf", root, sequence="keyboard")
    assert scene.train[1].time == pytest.approx(4 / 7)


def test_mask_benchmark_layout_gt(tmp_path):
    root = write_nerfies(tmp_path / "hypernerf" / "americano", n_items=12, gt=False)
    gt = tmp_path / "HyperNeRF-Mask" / "americano" / "gt_masks"
    gt.mkdir(parents=True)
    for k in range(3):
        cv2.imwrite(str(gt / f"{k:05d}.png"), np.zeros((12, 16), np.uint8))
    (gt / "cup").mkdir()  # per-object subdir is ignored for alignment
    scene = load_scene("hypernerf", root)
    assert [p.name for p in scene.gt_masks] == ["00000.png", "00001.png", "00002.png"]


# -- bad input --------------------------------------------------------------------------
def test_missing_camera_file(tmp_path):
    root = write_nerfies(tmp_path / "s", n_items=8, gt=False)
    victim = json.loads((root / "dataset.json").read_text())["ids"][4]
    (root / "camera" / f"{victim}.json").unlink()
    with pytest.raises(DatasetError, match=rf"{victim}\.json: camera file not found"):
        load_scene("hypernerf", root, "americano")


def test_malformed_json(tmp_path):
    root = write_nerfies(tmp_path / "s", n_items=8, gt=False)
    (root / "metadata.json").write_text('{"a": ')
    with pytest.raises(DatasetError, match=r"metadata\.json: malformed JSON \(line"):
        load_scene("hypernerf", root, "americano")


def test_nan_in_pose(tmp_path):
    root = write_nerfies(tmp_path / "s", n_items=8, gt=False)
    item = json.loads((root / "dataset.json").read_text())["ids"][0]
    p = root / "camera" / f"{item}.json"
    d = json.loads(p.read_text())
    d["position"][1] = float("nan")
    p.write_text(json.dumps(d))
    with pytest.raises(DatasetError, match="position contains NaN or Inf"):
        load_scene("hypernerf", root, "americano")


def test_image_size_disagrees_with_camera(tmp_path):
    root = write_nerfies(tmp_path / "s", n_items=8, gt=False)
    item = json.loads((root / "dataset.json").read_text())["ids"][2]
    cv2.imwrite(str(root / "rgb" / "2x" / f"{item}.png"), np.zeros((13, 16, 3), np.uint8))
    with pytest.raises(DatasetError, match=r"image is 16x13 but camera.* says 16x12"):
        load_scene("hypernerf", root, "americano")


def test_unknown_sequence(tmp_path):
    root = write_nerfies(tmp_path / "s", n_items=8, gt=False)
    with pytest.raises(DatasetError, match="unknown sequence 'nope'"):
        load_scene("hypernerf", root, "nope")


def test_missing_and_extra_gt_frames(tmp_path):
    root = write_nerfies(tmp_path / "s", n_items=12, n_gt=2)
    with pytest.raises(DatasetError, match=r"missing ground-truth frame\(s\) 00002.png"):
        load_scene("hypernerf", root, "americano")
    root2 = write_nerfies(tmp_path / "t", n_items=12, n_gt=4)
    with pytest.raises(DatasetError, match=r"extra ground-truth frame\(s\) 00003.png"):
        load_scene("hypernerf", root2, "americano")


def test_gt_size_mismatch(tmp_path):
    root = write_nerfies(tmp_path / "s", n_items=12)
    cv2.imwrite(str(root / "gt_masks" / "00001.png"), np.zeros((24, 32), np.uint8))
    with pytest.raises(DatasetError, match=r"00001.png: ground-truth mask is 32x24"):
        load_scene("hypernerf", root, "americano")


def test_synthetic_manifest_sets_variant(tmp_path):
    root = write_nerfies(tmp_path / "s", n_items=8, gt=False)
    (root / "synthetic").mkdir()
    (root / "synthetic" / "manifest.json").write_text("{}")
    scene = load_scene("hypernerf", root, "americano")
    assert scene.variant == "synthetic"
    assert scene.truth.manifest_path == root / "synthetic" / "manifest.json"
    assert scene.truth.objects == () and scene.truth.interest_ids == [] and scene.truth.info["seed"] is None
