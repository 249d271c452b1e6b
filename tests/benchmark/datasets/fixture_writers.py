"""Writers of tiny scenes in the publishers' real on-disk formats, for the loader tests."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from trase.camera import look_at


def _png(path: Path, w: int, h: int, value: int = 0) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.full((h, w, 3), value, np.uint8)
    img[: h // 2, : w // 2] = 200  # something to see
    cv2.imwrite(str(path), img)


def _mask(path: Path, w: int, h: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    m = np.zeros((h, w), np.uint8)
    m[2:5, 3:7] = 255
    cv2.imwrite(str(path), m)


def nerfies_camera_dict(w2c: np.ndarray, *, f=40.0, pp=(16.5, 11.0), skew=0.0, aspect=1.0,
                        radial=(0.01, -0.002, 0.0), tangential=(0.001, -0.0005), size=(32, 24),
                        tangential_key="tangential_distortion") -> dict:
    R = w2c[:3, :3]
    c = -R.T @ w2c[:3, 3]
    return {
        "orientation": R.tolist(), "position": c.tolist(), "focal_length": f,
        "principal_point": list(pp), "skew": skew, "pixel_aspect_ratio": aspect,
        "radial_distortion": list(radial), tangential_key: list(tangential),
        "image_size": list(size),
    }


def write_nerfies(root: Path, n_items: int = 12, *, two_cameras: bool = False,
                  time_key: str = "time_id", gt: bool = True, n_gt: int | None = None) -> Path:
    """A nerfies scene: 1x images 32x24, rgb/2x images 16x12, ``n_items`` items."""
    root.mkdir(parents=True, exist_ok=True)
    ids = [f"{'left' if not two_cameras or i % 2 == 0 else 'right'}1_{i:06d}" for i in range(n_items)]
    for i, item in enumerate(ids):
        eye = [np.cos(i * 0.3) * 2.0, -3.0, 0.5 + 0.05 * i]
        cam = nerfies_camera_dict(look_at(eye, [0, 0, 0]))
        (root / "camera").mkdir(exist_ok=True)
        (root / "camera" / f"{item}.json").write_text(json.dumps(cam))
        _png(root / "rgb" / "2x" / f"{item}.png", 16, 12)
    meta = {item: {time_key: i // 2 if two_cameras else i, "camera_id": 0} for i, item in enumerate(ids)}
    if time_key != "time_id":
        for m in meta.values():
            m["time_id"] = None
            del m["time_id"]
    (root / "metadata.json").write_text(json.dumps(meta))
    ds = {"count": n_items, "num_exemplars": n_items, "ids": ids}
    if two_cameras:
        ds["train_ids"] = [i for i in ids if i.startswith("left")]
        ds["val_ids"] = [i for i in ids if i.startswith("right")]
    (root / "dataset.json").write_text(json.dumps(ds))
    (root / "scene.json").write_text(json.dumps({"scale": 0.5, "center": [0.1, 0.2, 0.3], "near": 0.1, "far": 5.0}))
    np.save(root / "points.npy", np.random.default_rng(0).normal(size=(50, 3)))
    if gt:
        n_test = n_gt if n_gt is not None else (len(ds["val_ids"]) if two_cameras else len(ids[2::4]))
        for k in range(n_test):
            _mask(root / "gt_masks" / f"{k:05d}.png", 16, 12)
    return root


# -- Neu3D -------------------------------------------------------------------------------
def neu3d_c2w_opencv(i: int) -> np.ndarray:
    eye = [np.cos(i * 0.4) * 3.0, np.sin(i * 0.4) * 3.0, 0.3]
    return np.linalg.inv(look_at(eye, [0, 0, 0]))


def write_neu3d(root: Path, n_cams: int = 4, n_frames: int = 6, size=(32, 24), focal=30.0,
                poses_rows: int | None = None, gt_frames: int | None = None) -> Path:
    """A Neu3D scene: camNN.mp4 videos (size W x H) + poses_bounds.npy in LLFF axes."""
    root.mkdir(parents=True, exist_ok=True)
    W, H = size
    rows = []
    for i in range(n_cams):
        c2w = neu3d_c2w_opencv(i)
        # OpenCV [right, down, forward] -> LLFF [down, right, back]
        llff = np.stack([c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3]], axis=1)
        m = np.concatenate([llff, np.array([[H], [W], [focal]])], axis=1)  # [3, 5]
        rows.append(np.concatenate([m.ravel(), [0.5, 8.0]]))
    pb = np.stack(rows)
    if poses_rows is not None:
        pb = pb[:poses_rows] if poses_rows <= len(pb) else np.concatenate([pb, pb[: poses_rows - len(pb)]])
    np.save(root / "poses_bounds.npy", pb)
    for i in range(n_cams):
        write_video(root / f"cam{i:02d}.mp4", n_frames, W, H, seed=i)
    if gt_frames:
        for k in range(gt_frames):
            _mask(root / "gt_masks" / f"{k:05d}.png", W // 2, H // 2)
    return root


def write_video(path: Path, n_frames: int, W: int, H: int, seed: int = 0) -> None:
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (W, H))
    assert vw.isOpened()
    for k in range(n_frames):
        img = np.full((H, W, 3), 20 * k + seed, np.uint8)
        vw.write(img)
    vw.release()


# -- Immersive ----------------------------------------------------------------------------
def immersive_model(i: int, *, W=64, H=48, f=20.0, k=(0.05, -0.01)) -> dict:
    w2c = look_at([np.cos(i * 0.5) * 2.0, -2.0, np.sin(i * 0.5)], [0, 0, 0])
    rotvec = Rotation.from_matrix(w2c[:3, :3]).as_rotvec()
    c = -w2c[:3, :3].T @ w2c[:3, 3]
    return {"name": f"camera_{i + 1:04d}", "position": c.tolist(), "orientation": rotvec.tolist(),
            "focal_length": f, "pixel_aspect_ratio": 1.0, "principal_point": [W / 2 + 1.5, H / 2 - 1.0],
            "width": float(W), "height": float(H), "radial_distortion": [k[0], k[1], 0.0],
            "projection_type": "fisheye"}


def write_immersive(root: Path, n_cams: int = 3, n_frames: int = 4, W: int = 64, H: int = 48) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    models = [immersive_model(i, W=W, H=H) for i in range(n_cams)]
    (root / "models.json").write_text(json.dumps(models))
    for m in models:
        write_video(root / f"{m['name']}.mp4", n_frames, W, H)
    return root


# -- Technicolor --------------------------------------------------------------------------
def write_technicolor(root: Path, name: str = "Birthday", frames=range(151, 154), n_cams: int = 4,
                      W: int = 32, H: int = 16, rows_override: list[str] | None = None) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    lines = ["f cu cv ar sk qw qx qy qz tx ty tz"]
    for c in range(n_cams):
        w2c = look_at([c * 0.1 - 0.15, -3.0, (c // 2) * 0.1], [0, 0, 0])
        q = Rotation.from_matrix(w2c[:3, :3]).as_quat()  # x, y, z, w
        t = w2c[:3, 3]
        lines.append(f"20.0 {W / 2 + 1.0} {H / 2 - 1.0} 1.0 0.0 {q[3]} {q[0]} {q[1]} {q[2]} {t[0]} {t[1]} {t[2]}")
    if rows_override is not None:
        lines = lines[:1] + rows_override
    (root / "cameras_parameters.txt").write_text("\n".join(lines) + "\n")
    for fr in frames:
        for c in range(n_cams):
            _png(root / f"{name}_undist_{fr:05d}_{c:02d}.png", W, H, value=fr % 50)
    return root
