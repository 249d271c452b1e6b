import json

import cv2
import numpy as np
import pytest
from fixture_writers import write_neu3d
from plyfile import PlyData, PlyElement

from benchmark.cli import main
from benchmark.datasets import DatasetError, load_scene
from trase.camera import look_at


def _ply(path, pts):
    v = np.array([tuple(p) + (10, 20, 30) for p in pts],
                 dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    PlyData([PlyElement.describe(v, "vertex")]).write(str(path))


def _trase_layout(root, fmt, cams, frames, W=16, H=12):
    """What the public code's *2blender.py writes: transforms_{train,test}.json + images_2x."""
    root.mkdir(parents=True)
    out = {"train": [], "test": []}
    w2cs = {}
    for i, cam in enumerate(cams):
        w2c = look_at([np.cos(i) * 3, np.sin(i) * 3, 0.4], [0, 0, 0])
        w2cs[cam] = w2c
        for fr in frames:
            fp = f"images_2x/{cam}_{fr:04d}"
            img = np.full((H, W, 3), 50, np.uint8)
            (root / "images_2x").mkdir(exist_ok=True)
            cv2.imwrite(str(root / (fp + ".png")), img)
            if fmt == "neu3d":
                c2w = np.linalg.inv(w2c)
                c2w[:3, 1:3] *= -1  # OpenCV -> OpenGL camera axes
                entry = {"file_path": fp, "transform_matrix": c2w.tolist(), "time": fr / 30.0}
            else:
                entry = {"file_path": fp, "transform_matrix": w2c.tolist(), "time": fr / 30.0,
                         "w": W, "h": H, "fl_x": 12.0, "fl_y": 12.0, "cx": W / 2, "cy": H / 2}
            out["test" if i == 0 else "train"].append(entry)
    for split, frs in out.items():
        d = {"frames": frs}
        if fmt == "neu3d":
            d.update({"w": W, "h": H, "fl_x": 12.0, "fl_y": 12.0, "cx": W // 2, "cy": H // 2})
        (root / f"transforms_{split}.json").write_text(json.dumps(d))
    _ply(root / "points3d.ply", np.random.default_rng(0).normal(size=(30, 3)))
    return w2cs


def test_neu3d_transforms_layout(tmp_path):
    root = tmp_path / "coffee_martini"
    w2cs = _trase_layout(root, "neu3d", ["cam00", "cam01", "cam02"], range(3))
    scene = load_scene("neu3d", root)
    assert [v.name for v in scene.test] == ["cam00/00000", "cam00/00001", "cam00/00002"]
    v = scene.train[0]
    np.testing.assert_allclose(v.camera.w2c, w2cs["cam01"], atol=1e-9)
    assert v.native_camera is None and scene.points.shape == (30, 3)
    assert scene.point_colors[0] == pytest.approx([10 / 255, 20 / 255, 30 / 255])
    assert scene.test[1].time == pytest.approx(1 / 3)


def test_technicolor_transforms_layout_renames_cameras_and_keeps_range(tmp_path):
    root = tmp_path / "Fabien"
    w2cs = _trase_layout(root, "technicolor", ["camera_0000", "camera_0001"], range(50, 53))
    scene = load_scene("technicolor", root)
    # frame 50 is outside Fabien's range 51-100 and is dropped
    assert [v.name for v in scene.test] == ["cam00/00051", "cam00/00052"]
    assert [v.time for v in scene.test] == [0.0, 0.5]
    np.testing.assert_allclose(scene.train[0].camera.w2c, w2cs["camera_0001"])


def test_transforms_missing_point_cloud(tmp_path):
    root = tmp_path / "Fabien"
    _trase_layout(root, "technicolor", ["camera_0000", "camera_0001"], range(51, 53))
    (root / "points3d.ply").unlink()
    with pytest.raises(DatasetError, match=r"points3d.ply: missing point cloud"):
        load_scene("technicolor", root)


def test_cli_datasets_json(capsys):
    assert main(["datasets", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["technicolor"]["frame_ranges"]["Painter"] == [100, 149]
    assert data["hypernerf"]["display_name"] == "HyperNeRF-Mask"


def test_cli_datasets_table(capsys):
    assert main(["datasets"]) == 0
    out = capsys.readouterr().out
    for name in ("NeRF-DS-Mask", "sear_steak", "camera_0001", "Theater", "synthetic-tiny", "synthetic-medium-hard"):
        assert name in out
    assert "densify" in out and "warm-up" in out  # the last column, whole when not printed to a terminal


def test_cli_prepare_and_bad_input(tmp_path, capsys):
    raw = write_neu3d(tmp_path / "neu3d" / "flame_steak", n_cams=2, n_frames=1)
    np.save(raw / "poses_bounds.npy", np.zeros((2, 5)))
    assert main(["prepare", "neu3d", str(raw), str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "poses_bounds.npy: expected shape [N, 17]" in err
    # a dataset folder: every known sequence folder inside is prepared (and fails the same way)
    assert main(["prepare", "neu3d", str(tmp_path / "neu3d"), str(tmp_path / "o2")]) == 1
    assert "flame_steak/poses_bounds.npy" in capsys.readouterr().err


def test_cli_prepare_dataset_folder_with_frames(tmp_path, capsys):
    write_neu3d(tmp_path / "neu3d" / "flame_steak", n_cams=2, n_frames=2)
    write_neu3d(tmp_path / "neu3d" / "sear_steak", n_cams=2, n_frames=2)
    assert main(["prepare", "neu3d", str(tmp_path / "neu3d"), str(tmp_path / "out"), "--frames", "0-1"]) == 0
    for seq in ("flame_steak", "sear_steak"):
        m = json.loads((tmp_path / "out" / seq / "prepared.json").read_text())
        assert m["frames"] == [0, 1] and m["sequence"] == seq
    assert main(["prepare", "neu3d", str(tmp_path / "neu3d"), str(tmp_path / "out"), "--frames", "3"]) == 1
    assert "--frames" in capsys.readouterr().err
