import json

import cv2
import numpy as np
import pytest
from fixture_writers import (
    immersive_model,
    neu3d_c2w_opencv,
    write_immersive,
    write_neu3d,
    write_technicolor,
)

from benchmark.datasets import DATASETS, DatasetError, load_scene
from benchmark.datasets.immersive import read_models
from benchmark.datasets.neu3d import read_poses_bounds
from benchmark.datasets.prepare import prepare_sequence
from benchmark.datasets.rectify import make_rectifier
from benchmark.datasets.technicolor import read_cameras_parameters


def _quat_to_R(w, x, y, z):  # by hand, Hamilton convention (COLMAP)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


# -- Neu3D -------------------------------------------------------------------------------
def test_neu3d_poses_bounds_axes_and_projection(tmp_path):
    root = write_neu3d(tmp_path / "neu3d" / "sear_steak", n_cams=3, n_frames=1)
    cams, bounds = read_poses_bounds(root / "poses_bounds.npy")
    assert bounds.shape == (3, 2)
    pts = np.random.default_rng(0).uniform(-0.5, 0.5, size=(10, 3))
    for i, cam in enumerate(cams):
        w2c = np.linalg.inv(neu3d_c2w_opencv(i))
        np.testing.assert_allclose(cam.w2c, w2c, atol=1e-12)
        K = np.array([[30.0, 0, 16.0], [0, 30.0, 12.0], [0, 0, 1]])
        ref, _ = cv2.projectPoints(pts, cv2.Rodrigues(w2c[:3, :3])[0], w2c[:3, 3], K, None)
        uv, z = cam.project(pts)
        assert (z > 0).all()
        np.testing.assert_allclose(uv, ref[:, 0], atol=1e-9)


def test_neu3d_prepare_then_load(tmp_path):
    raw = write_neu3d(tmp_path / "neu3d" / "sear_steak", n_cams=3, n_frames=5, gt_frames=4)
    seen = []
    m = prepare_sequence("neu3d", raw, raw / "prepared", frames=[0, 1, 2, 3],
                         on_start=seen.append, on_image=lambda: seen.append("i"))
    assert seen[0] == 12 and seen.count("i") == 12
    assert m["cameras"] == ["cam00", "cam01", "cam02"] and m["resolution"] == [16, 12]
    assert m["points_source"] == "frustum_random"
    scene = load_scene("neu3d", raw)  # finds raw/prepared
    assert scene.sequence == "sear_steak"
    assert [v.name for v in scene.test] == ["cam00/00000", "cam00/00001", "cam00/00002", "cam00/00003"]
    assert len(scene.train) == 8
    assert [v.time for v in scene.test] == [0.0, 0.25, 0.5, 0.75]
    assert scene.test[2].frame == 2
    v = scene.train[0]
    assert v.camera.is_pinhole and (v.camera.width, v.camera.height) == (16, 12)
    assert v.camera.fx == pytest.approx(15.0) and v.camera.cx == pytest.approx(8.0)
    assert v.native_camera.width == 32
    img = cv2.imread(str(v.image_path))
    assert img.shape == (12, 16, 3)
    assert len(scene.gt_masks) == 4  # raw/gt_masks found from raw/prepared
    # frustum points lie within the Neu3D bounds of some camera
    assert np.isfinite(scene.points).all() and scene.points.shape == (20000, 3)


def test_prepared_manifest_is_relative_and_reproducible(tmp_path):
    import shutil

    raw = write_neu3d(tmp_path / "a" / "sear_steak", n_cams=3, n_frames=2, gt_frames=2)
    prepare_sequence("neu3d", raw, raw / "prepared", frames=[0, 1])
    first = (raw / "prepared" / "prepared.json").read_bytes()
    m = json.loads(first)
    assert m["source_dir"] == ".." and "created" not in m  # no absolute path, no timestamp
    moved = tmp_path / "b" / "sear_steak"
    shutil.move(str(raw), str(moved))
    assert len(load_scene("neu3d", moved).test) == 2  # a moved folder still loads
    (moved / "prepared" / "prepared.json").unlink()
    prepare_sequence("neu3d", moved, moved / "prepared", frames=[0, 1])
    assert (moved / "prepared" / "prepared.json").read_bytes() == first  # same inputs, same bytes


def test_prepare_is_resumable(tmp_path):
    raw = write_neu3d(tmp_path / "sear_steak", n_cams=2, n_frames=3)
    out = tmp_path / "out"
    prepare_sequence("neu3d", raw, out, frames=[0, 1])
    victim = out / "images" / "cam01" / "00001.png"
    victim.unlink()
    before = (out / "images" / "cam00" / "00000.png").stat().st_mtime_ns
    totals = []
    prepare_sequence("neu3d", raw, out, frames=[0, 1], on_start=totals.append)
    assert totals == [1] and victim.is_file()
    assert (out / "images" / "cam00" / "00000.png").stat().st_mtime_ns == before


def test_neu3d_poses_wrong_shape(tmp_path):
    raw = write_neu3d(tmp_path / "sear_steak", n_cams=2, n_frames=1)
    np.save(raw / "poses_bounds.npy", np.zeros((2, 15)))
    with pytest.raises(DatasetError, match=r"poses_bounds.npy: expected shape \[N, 17\], got \[2, 15\]"):
        prepare_sequence("neu3d", raw, tmp_path / "out")


def test_neu3d_more_poses_than_videos(tmp_path):
    raw = write_neu3d(tmp_path / "sear_steak", n_cams=2, n_frames=1, poses_rows=3)
    with pytest.raises(DatasetError, match="3 poses for 2 videos"):
        prepare_sequence("neu3d", raw, tmp_path / "out")


def test_neu3d_nan_pose(tmp_path):
    raw = write_neu3d(tmp_path / "sear_steak", n_cams=2, n_frames=1)
    pb = np.load(raw / "poses_bounds.npy")
    pb[1, 3] = np.inf
    np.save(raw / "poses_bounds.npy", pb)
    with pytest.raises(DatasetError, match="row 1 contains NaN or Inf"):
        prepare_sequence("neu3d", raw, tmp_path / "out")


def test_neu3d_video_size_disagrees_with_pose(tmp_path):
    raw = write_neu3d(tmp_path / "sear_steak", n_cams=2, n_frames=1)
    pb = np.load(raw / "poses_bounds.npy")
    pb[1, 9] = 30  # W of row 1 (3x5 row-major: [H, W, f] at 4, 9, 14)
    np.save(raw / "poses_bounds.npy", pb)
    with pytest.raises(DatasetError, match=r"cam01.mp4: video is 32x24 but its poses_bounds.npy row says 30x24"):
        prepare_sequence("neu3d", raw, tmp_path / "out")


def test_raw_multiview_without_prepare_says_what_to_run(tmp_path):
    raw = write_neu3d(tmp_path / "sear_steak", n_cams=2, n_frames=1)
    with pytest.raises(DatasetError, match="run `trase-bench prepare neu3d"):
        load_scene("neu3d", raw)


def test_video_too_short(tmp_path):
    raw = write_neu3d(tmp_path / "sear_steak", n_cams=2, n_frames=2)
    with pytest.raises(DatasetError, match=r"cam00.mp4: video ends at frame 2, frame 2 is needed"):
        prepare_sequence("neu3d", raw, tmp_path / "out", frames=[0, 1, 2])


def test_prepared_image_size_disagrees(tmp_path):
    raw = write_neu3d(tmp_path / "sear_steak", n_cams=2, n_frames=2)
    out = tmp_path / "sear_steak_prep"
    prepare_sequence("neu3d", raw, out, frames=[0, 1])
    cv2.imwrite(str(out / "images" / "cam01" / "00001.png"), np.zeros((5, 5, 3), np.uint8))
    with pytest.raises(DatasetError, match=r"00001.png: image is 5x5 but camera cam01"):
        load_scene("neu3d", out, "sear_steak")


# -- Immersive ----------------------------------------------------------------------------
def test_read_models_matches_cv2_fisheye(tmp_path):
    models = [immersive_model(i) for i in range(3)]
    p = tmp_path / "models.json"
    p.write_text(json.dumps(models))
    cams = read_models(p)
    pts = np.random.default_rng(2).uniform(-0.4, 0.4, size=(15, 3))
    for m, cam in zip(models, cams):
        assert cam.fisheye and cam.name == m["name"]
        rvec = np.array(m["orientation"])
        R = cv2.Rodrigues(rvec)[0]
        tvec = -R @ np.array(m["position"])
        K = np.array([[m["focal_length"], 0, m["principal_point"][0]],
                      [0, m["focal_length"], m["principal_point"][1]], [0, 0, 1.0]])
        D = np.array([m["radial_distortion"][0], m["radial_distortion"][1], 0.0, 0.0])
        ref, _ = cv2.fisheye.projectPoints(pts[None], rvec, tvec, K, D)
        uv, _ = cam.project(pts)
        np.testing.assert_allclose(uv, ref[0], atol=1e-8)


def test_fisheye_undistortion_moves_content_to_pinhole_projection():
    cam = read_models_from([immersive_model(0, W=160, H=120, f=50.0, k=(0.08, -0.02))])[0]
    rect = make_rectifier(DATASETS["immersive"], cam)
    pin = rect.camera
    assert pin.is_pinhole and (pin.width, pin.height) == (80, 60)
    assert (pin.cx, pin.cy) == (40.0, 30.0)
    # a world point seen off-centre by both cameras
    ray = pin.pixel_rays(np.array([[55.0, 18.0]]))[0]
    X = pin.c2w[:3, :3] @ (ray * 2.0) + pin.center
    uv_fish, _ = cam.project(X[None])
    img = np.zeros((120, 160, 3), np.uint8)
    cv2.circle(img, (int(uv_fish[0, 0]), int(uv_fish[0, 1])), 3, (255, 255, 255), -1)
    out = rect(img)[..., 0].astype(float)
    ys, xs = np.nonzero(out > 60)
    w = out[ys, xs]
    centroid = np.array([(xs * w).sum() / w.sum() + 0.5, (ys * w).sum() / w.sum() + 0.5])
    uv_pin, _ = pin.project(X[None])
    assert np.linalg.norm(centroid - uv_pin[0]) < 1.0


def read_models_from(models, tmp=None):
    import tempfile
    from pathlib import Path

    d = Path(tempfile.mkdtemp())
    (d / "models.json").write_text(json.dumps(models))
    return read_models(d / "models.json")


def test_immersive_prepare_and_load(tmp_path):
    raw = write_immersive(tmp_path / "immersive" / "10_Alexa_Meade_Face_Paint_1", n_cams=3, n_frames=3)
    out = tmp_path / "immersive" / "10_Alexa_1"
    m = prepare_sequence("immersive", raw, out, frames=[0, 1, 2])
    assert m["sequence"] == "10_Alexa_1"
    scene = load_scene("immersive", out)
    assert [v.name for v in scene.test] == ["camera_0001/00000", "camera_0001/00001", "camera_0001/00002"]
    assert scene.test[1].time == pytest.approx(1 / 3)
    assert scene.train[0].native_camera.fisheye and scene.train[0].camera.is_pinhole


def test_immersive_camera_without_video(tmp_path):
    raw = write_immersive(tmp_path / "01_Welder", n_cams=2, n_frames=1)
    (raw / "camera_0002.mp4").unlink()
    with pytest.raises(DatasetError, match=r"models.json: 2 cameras for 1 videos; no video for camera_0002"):
        prepare_sequence("immersive", raw, tmp_path / "out")


def test_immersive_malformed_models(tmp_path):
    raw = write_immersive(tmp_path / "01_Welder", n_cams=2, n_frames=1)
    (raw / "models.json").write_text("[{")
    with pytest.raises(DatasetError, match=r"models.json: malformed JSON \(line"):
        prepare_sequence("immersive", raw, tmp_path / "out")
    models = [immersive_model(0), immersive_model(1)]
    del models[1]["focal_length"]
    (raw / "models.json").write_text(json.dumps(models))
    with pytest.raises(DatasetError, match=r"missing key 'focal_length' in camera 'camera_0002'"):
        prepare_sequence("immersive", raw, tmp_path / "out")


# -- Technicolor --------------------------------------------------------------------------
def test_technicolor_cameras_match_hand_arithmetic(tmp_path):
    raw = write_technicolor(tmp_path / "Birthday", frames=[151], n_cams=2)
    cams = read_cameras_parameters(raw / "cameras_parameters.txt", 32, 16)
    rows = (raw / "cameras_parameters.txt").read_text().splitlines()[1:]
    X = np.array([[0.1, -0.2, 0.3]])
    for row, cam in zip(rows, cams):
        f, cu, cv, ar, sk, qw, qx, qy, qz, tx, ty, tz = map(float, row.split())
        R = _quat_to_R(qw, qx, qy, qz)
        pc = R @ X[0] + [tx, ty, tz]
        uv, _ = cam.project(X)
        x, y = pc[0] / pc[2], pc[1] / pc[2]
        np.testing.assert_allclose(uv[0], [f * x + sk * y + cu, f * ar * y + cv], atol=1e-9)


def test_technicolor_principal_point_shift():
    raw_cam = read_cameras_parameters_from_row("20.0 17.0 7.0 1.0 0.0 1 0 0 0 0 0 1", 64, 32)
    rect = make_rectifier(DATASETS["technicolor"], raw_cam)
    assert (rect.camera.cx, rect.camera.cy) == (16.0, 8.0)
    X = np.array([[0.3, -0.1, 0.0]])  # camera at z=-1 looking +z
    uv_native, _ = raw_cam.project(X)
    img = np.zeros((32, 64, 3), np.uint8)
    u, v = int(uv_native[0, 0]), int(uv_native[0, 1])
    img[v - 2:v + 2, u - 2:u + 2] = 255
    out = rect(img)[..., 0].astype(float)
    ys, xs = np.nonzero(out)
    w = out[ys, xs]
    centroid = np.array([(xs * w).sum() / w.sum() + 0.5, (ys * w).sum() / w.sum() + 0.5])
    uv_train, _ = rect.camera.project(X)
    assert np.linalg.norm(centroid - uv_train[0]) < 0.6


def read_cameras_parameters_from_row(row, W, H):
    import tempfile
    from pathlib import Path

    p = Path(tempfile.mkdtemp()) / "cameras_parameters.txt"
    p.write_text("f cu cv ar sk qw qx qy qz tx ty tz\n" + row + "\n")
    return read_cameras_parameters(p, W, H)[0]


def test_technicolor_prepare_and_load_frame_range(tmp_path):
    raw = write_technicolor(tmp_path / "Birthday", frames=range(151, 154), n_cams=3)
    out = tmp_path / "prep"
    prepare_sequence("technicolor", raw, out, frames=[151, 152, 153])
    scene = load_scene("technicolor", out, "Birthday")
    assert [v.name for v in scene.test] == ["cam00/00151", "cam00/00152", "cam00/00153"]
    assert scene.test[0].camera.cx == 8.0 and scene.test[0].camera.width == 16


def test_technicolor_bad_row(tmp_path):
    raw = write_technicolor(tmp_path / "Birthday", frames=[151], n_cams=2,
                            rows_override=["20 16 8 1 0 1 0 0 0 0 0", "20 16 8 1 0 1 0 0 0 0 0 nan"])
    with pytest.raises(DatasetError, match=r"row 1 has 11 values, expected 12"):
        prepare_sequence("technicolor", raw, tmp_path / "out", frames=[151])


def test_technicolor_missing_frame(tmp_path):
    raw = write_technicolor(tmp_path / "Birthday", frames=[151, 152], n_cams=2)
    (raw / "Birthday_undist_00152_01.png").unlink()
    with pytest.raises(DatasetError, match=r"missing image for camera cam01 frame 152"):
        prepare_sequence("technicolor", raw, tmp_path / "out", frames=[151, 152])


def test_prepare_unknown_sequence(tmp_path):
    raw = write_technicolor(tmp_path / "Train", frames=[151], n_cams=2)
    with pytest.raises(DatasetError, match="unknown sequence 'Train'; valid: Birthday"):
        prepare_sequence("technicolor", raw, tmp_path / "out")


def test_technicolor_truncated_png_is_completed_from_previous_frame(tmp_path):
    raw = write_technicolor(tmp_path / "Birthday", frames=[151, 152], n_cams=2)
    victim = raw / "Birthday_undist_00152_01.png"
    big = np.random.default_rng(0).integers(1, 255, size=(16, 32, 3), dtype=np.uint8)
    cv2.imwrite(str(victim), big)
    data = victim.read_bytes()
    victim.write_bytes(data[: len(data) // 2])  # cut the file
    m = prepare_sequence("technicolor", raw, tmp_path / "out", frames=[151, 152])
    assert m["repaired_images"] == ["Birthday_undist_00152_01.png"]
    (raw / "Birthday_undist_00151_01.png").unlink()
    raw2 = write_technicolor(tmp_path / "b2" / "Birthday", frames=[151], n_cams=2)
    (raw2 / "Birthday_undist_00151_01.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match="truncated image and no previous frame"):
        prepare_sequence("technicolor", raw2, tmp_path / "out2", frames=[151])
