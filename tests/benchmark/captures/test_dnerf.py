"""A D-NeRF scene read as published (tests/data/dnerf/hook-tiny: a downscaled subset of the
public hook scene, scripts/make_dnerf_subset.py): splits, alpha, stray files, scaling."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from benchmark.captures import CaptureOptions, load_capture

HOOK = Path(__file__).resolve().parents[2] / "data" / "dnerf" / "hook-tiny"


@pytest.fixture
def hook(tmp_path, monkeypatch):
    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path / "cache"))
    return Path(shutil.copytree(HOOK, tmp_path / "hook"))


def test_dnerf_splits_alpha_and_stray_files(hook):
    (hook / "train" / "r_000_depth.png").write_bytes((hook / "train" / "r_000.png").read_bytes())
    scene = load_capture(hook, CaptureOptions(holdout="layout"))
    assert scene.extras["format"] == "transforms"
    assert [v.name for v in scene.train] == [f"train/r_{i:03d}" for i in (0, 20, 40, 60, 80, 99)]
    assert [v.name for v in scene.test] == ["test/r_000", "test/r_010"]
    assert [v.name for v in scene.validation] == ["val/r_000", "val/r_010"]  # never trained, never a test view
    notes = " | ".join(scene.extras["notices"])
    assert "the images carry alpha: composited over the run's background" in notes
    assert "2 validation views (transforms_val.json)" in notes
    assert "ignored 1 image(s) in train/ that no frame lists (e.g. r_000_depth.png)" in notes
    assert "initial points carved from the images' alpha" in notes  # D-NeRF ships no point cloud
    cam = scene.train[0].camera  # intrinsics from camera_angle_x at the images' size
    assert (cam.width, cam.height) == (40, 40) and cam.K[0, 0] == pytest.approx(20 / np.tan(0.6911112070083618 / 2))
    # without --holdout layout the test views train too; the validation views never do
    every = load_capture(hook)
    assert len(every.train) == 8 and every.test == [] and len(every.validation) == 2


def test_dnerf_at_half_size_without_a_copy(hook):
    full = load_capture(hook, CaptureOptions(holdout="layout", normalize=False))
    half = load_capture(hook, CaptureOptions(holdout="layout", normalize=False, image_scale=2))
    for a, b in zip(full.train + full.test + full.validation, half.train + half.test + half.validation):
        assert (b.camera.width, b.camera.height) == (20, 20)
        assert np.allclose(b.camera.K[:2], a.camera.K[:2] / 2) and np.array_equal(b.camera.w2c, a.camera.w2c)
    assert any("800x800" not in n and "40x40 -> 20x20" in n for n in half.extras["notices"])
    capped = load_capture(hook, CaptureOptions(max_side=16))
    assert {(v.camera.width, v.camera.height) for v in capped.train} == {(16, 16)}
    assert any("capture.max_side=16" in n for n in capped.extras["notices"])


def test_fit_measures_the_held_out_and_validation_views_on_the_runs_background(hook, tmp_path):
    import json

    from benchmark.captures.fit import FitOptions, fit_capture, next_steps
    from trase.checkpoint import load_model
    from trase.render_views import evaluate_images

    fast = ["geometry.train.iterations=60", "method.features.iterations=30", "geometry.train.white_background=true"]
    fit_json = fit_capture(FitOptions(hook, tmp_path / "fit", holdout="layout", overrides=fast,
                                      cache_dir=tmp_path / "fc", progress=False))
    rec = json.loads(fit_json.read_text())
    m = rec["image_measures"]
    assert rec["views"] == {"train": 6, "test": 2, "validation": 2}
    assert set(m) == {"test_psnr", "test_ssim", "validation_psnr", "validation_ssim"}
    assert all(np.isfinite(v) for v in m.values()) and 0 < m["test_ssim"] <= 1
    # measured over the white background the reconstruction trained on, not black
    scene = load_capture(hook, CaptureOptions(holdout="layout"))
    g, d = load_model(tmp_path / "fit" / "model")
    white = evaluate_images(g, d, scene.test, (1.0, 1.0, 1.0))
    black = evaluate_images(g, d, scene.test)
    assert m["test_psnr"] == pytest.approx(white["psnr"], abs=1e-3) and abs(white["psnr"] - black["psnr"]) > 0.5
    assert any("validation PSNR" in line for line in next_steps(fit_json))


def test_initial_points_carved_from_alpha_lie_inside_the_silhouettes(hook):
    import cv2

    from benchmark.captures.common import points_from_alpha

    scene = load_capture(hook, CaptureOptions(normalize=False))
    pts, cols = points_from_alpha(scene.train, n=500)
    again, _ = points_from_alpha(scene.train, n=500)
    assert pts.shape == (500, 3) and cols.shape == (500, 3) and np.array_equal(pts, again)  # deterministic
    assert cols.min() >= 0 and cols.max() <= 1
    inside, seen = np.zeros(len(pts)), np.zeros(len(pts))
    for v in scene.train:
        alpha = cv2.imread(str(v.image_path), cv2.IMREAD_UNCHANGED)[:, :, 3] >= 128
        uv, z = v.camera.project(pts)
        u, w = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        ok = (z > 0) & (u >= 0) & (u < 40) & (w >= 0) & (w < 40)
        seen += ok
        inside[ok] += alpha[w[ok], u[ok]]
    assert np.all(inside >= 0.5 * seen) and np.all(seen > 0)
    # the random points the reader drew before: most of them fall outside the silhouettes
    from benchmark.captures.common import points_in_view

    rand = points_in_view(scene.train, 500)
    hits = np.zeros(len(rand))
    for v in scene.train:
        alpha = cv2.imread(str(v.image_path), cv2.IMREAD_UNCHANGED)[:, :, 3] >= 128
        uv, z = v.camera.project(rand)
        u, w = np.clip(np.floor(uv[:, 0]).astype(int), 0, 39), np.clip(np.floor(uv[:, 1]).astype(int), 0, 39)
        hits += alpha[w, u]
    assert np.mean(hits >= 0.5 * len(scene.train)) < 0.5
    # images without alpha outline nothing: no carving
    for v in scene.train:
        cv2.imwrite(str(v.image_path), cv2.imread(str(v.image_path))[:, :, :3])
    assert points_from_alpha(scene.train, n=50) is None
