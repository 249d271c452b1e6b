"""The capture readers on the layouts as their tools write them: cameras, times, points, the
holdout rule, format detection."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmark.captures import CaptureOptions, detect_format, load_capture
from benchmark.captures.common import normalization, order_times, points_in_view, times_from_values
from benchmark.datasets.errors import DatasetError


def _same_cameras(reference, loaded, check_time=True):
    by_name = {Path(v.name).name: v for v in loaded}
    for ref in reference:
        got = by_name[ref.name]
        assert np.allclose(got.camera.K, ref.camera.K, atol=1e-6)
        assert np.allclose(got.camera.w2c, ref.camera.w2c, atol=1e-6)
        assert (got.camera.width, got.camera.height) == (ref.camera.width, ref.camera.height)
        if check_time:
            assert got.camera.time == pytest.approx(ref.camera.time, abs=1e-9)


@pytest.mark.parametrize("layout", ["nerfies", "colmap", "transforms"])
def test_each_layout_is_detected_and_reads_back_the_scene(layout, capture_dirs, tiny_scene):
    assert detect_format(capture_dirs[layout]) == layout
    scene = load_capture(capture_dirs[layout], CaptureOptions(normalize=False))
    views = tiny_scene.train + tiny_scene.test
    expected = {"nerfies": views[:4], "colmap": views, "transforms": views}[layout]
    assert scene.dataset == "capture" and scene.extras["format"] == layout
    assert sorted(Path(v.name).name for v in scene.train) == sorted(v.name for v in expected)
    assert scene.test == [] and scene.gt_masks == [] and scene.truth is None  # all views train
    # nerfies times: time_id / max over the capture's own items (its layout's rule)
    _same_cameras(expected, scene.train, check_time=layout == "transforms")
    assert np.allclose(np.sort(scene.points, 0), np.sort(tiny_scene.points, 0), atol=1e-4)


def test_nerfies_capture_uses_colmap_points_in_the_camera_frame_and_counts_dropped_images(capture_dirs, tiny_scene):
    scene = load_capture(capture_dirs["nerfies"])
    assert not (capture_dirs["nerfies"] / "points.npy").exists()
    assert scene.point_colors is not None and len(scene.points) == len(tiny_scene.points)
    assert any(n.startswith("ignored 2 image(s) in rgb/2x with no id in dataset.json") for n in scene.extras["notices"])
    frames = sorted(v.frame for v in scene.train)
    assert [v.time for v in sorted(scene.train, key=lambda v: v.frame)] == [f / max(frames) for f in frames]


def test_nerfies_points_npy_wins_and_rgb_scale_is_a_setting(capture_copy, tmp_path, monkeypatch):
    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path / "cache"))
    d = capture_copy("nerfies")
    np.save(d / "points.npy", np.array([[2.25, -0.5, 0.125], [0.25, 1.5, 0.125]]))  # raw frame
    scene = load_capture(d, CaptureOptions(image_scale=4))
    assert np.allclose(scene.points, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # (p - center) * scale
    native = json.loads((d / "camera" / f"{scene.train[0].name}.json").read_text())["image_size"][0]
    assert scene.train[0].camera.width * 4 == native
    assert not (tmp_path / "cache").exists()  # the layout's own copy: nothing scaled
    # no rgb/8x: the 4x copy is scaled the rest of the way
    eighth = load_capture(d, CaptureOptions(image_scale=8))
    assert eighth.train[0].camera.width == round(native / 8)
    assert any("no copy at 1/8: scaled 1/2 from rgb/4x" in n for n in eighth.extras["notices"])
    with pytest.raises(DatasetError, match=r"rgb/3x: missing image folder rgb/3x \(found: 2x, 4x\), and none finer"):
        load_capture(d, CaptureOptions(image_scale=3))


def test_colmap_time_rules(capture_copy, tiny_scene):
    d = capture_copy("colmap")
    views = tiny_scene.train + tiny_scene.test
    t = load_capture(d, CaptureOptions(normalize=False))
    times = {v.name: v.time for v in views}
    lo, hi = min(times.values()), max(times.values())
    assert all(v.time == pytest.approx((times[v.name] - lo) / (hi - lo)) for v in t.train)  # times.json
    (d / "times.json").unlink()
    order = load_capture(d)
    names = sorted(v.name for v in order.train)
    assert [v.time for v in sorted(order.train, key=lambda v: v.name)] == [i / (len(names) - 1) for i in range(len(names))]
    assert "frame order" in " ".join(order.extras["notices"])
    assert {v.time for v in load_capture(d, CaptureOptions(time="static")).train} == {0.0}


def test_holdout_rules(capture_dirs):
    every = load_capture(capture_dirs["colmap"], CaptureOptions(holdout="every:3"))
    assert (len(every.train), len(every.test)) == (4, 2)
    ordered = sorted(every.train + every.test, key=lambda v: (v.time, v.name))
    assert [v.name for v in every.test] == [ordered[0].name, ordered[3].name]  # the first included
    layout = load_capture(capture_dirs["transforms"], CaptureOptions(holdout="layout"))
    assert len(layout.test) == 3 and all(v.name.startswith("images/") for v in layout.test)
    nothing = load_capture(capture_dirs["colmap"], CaptureOptions(holdout="layout"))
    assert nothing.test == [] and any("lists no test views" in n for n in nothing.extras["notices"])
    for bad in ("every:1", "every:x", "some"):
        with pytest.raises(DatasetError, match="--holdout"):
            CaptureOptions(holdout=bad)


def test_normalisation_is_a_similarity_that_keeps_projections(capture_dirs):
    raw = load_capture(capture_dirs["colmap"], CaptureOptions(normalize=False))
    norm = load_capture(capture_dirs["colmap"])
    center, scale = normalization(raw.points)
    assert np.allclose(norm.points, (raw.points - center) * scale)
    assert np.percentile(np.linalg.norm(norm.points, axis=1), 95) == pytest.approx(1.0, rel=1e-6)
    for a, b in zip(raw.train, norm.train):
        uv_a, z_a = a.camera.project(raw.points[:50])
        uv_b, z_b = b.camera.project(norm.points[:50])
        assert np.allclose(uv_a, uv_b, atol=1e-6) and np.allclose(z_a * scale, z_b)


def test_transforms_without_points_samples_where_the_cameras_look(capture_copy):
    d = capture_copy("transforms")
    (d / "points3d.ply").unlink()
    scene = load_capture(d, CaptureOptions(normalize=False))
    assert any("random initial points where the cameras look" in n for n in scene.extras["notices"])
    seen = np.zeros(len(scene.points), int)
    for v in scene.train:
        uv, z = v.camera.project(scene.points)
        seen += (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < v.camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < v.camera.height)
    assert (seen * 2 >= len(scene.train)).all()
    assert np.array_equal(points_in_view(scene.train, n=100), points_in_view(scene.train, n=100))  # deterministic


def test_order_times_and_detection_errors(tmp_path):
    assert order_times(["b", "a", "c"]) == {"a": (0, 0.0), "b": (1, 0.5), "c": (2, 1.0)}
    seconds = {"a": 10.0, "b": 12.0, "c": 10.0, "d": 14.0}
    assert times_from_values(seconds) == {"a": (0, 0.0), "b": (1, 0.5), "c": (0, 0.0), "d": (2, 1.0)}
    unit = {"a": 0.25, "b": 0.5}
    assert times_from_values(unit, keep_unit=True) == {"a": (0, 0.25), "b": (1, 0.5)}
    assert times_from_values(unit) == {"a": (0, 0.0), "b": (1, 1.0)}
    assert times_from_values({"a": 3.0, "b": 3.0}) == {"a": (0, 0.0), "b": (0, 0.0)}
    assert order_times(["only"]) == {"only": (0, 0.0)}
    with pytest.raises(DatasetError, match="no known capture layout"):
        detect_format(tmp_path)
    with pytest.raises(DatasetError, match="capture directory does not exist"):
        detect_format(tmp_path / "nope")


def test_a_prepared_multiview_recording_is_a_capture(tmp_path, monkeypatch):
    from benchmark.datasets import load_scene
    from benchmark.datasets.synthetic import generate

    d = generate("neu3d", tmp_path / "rec", seed=0, size="tiny")
    bench = load_scene("neu3d", d)
    assert detect_format(d) == "prepared"
    everything = load_capture(d, CaptureOptions(normalize=False))
    assert len(everything.train) == len(bench.train) + len(bench.test) and everything.test == []
    held = load_capture(d, CaptureOptions(holdout="layout", normalize=False))
    assert [v.name for v in held.test] == [v.name for v in bench.test]  # the registry's test camera
    assert np.array_equal(held.points, bench.points)
    # prepared frames have one size: any other is scaled on the fly, the cameras with them
    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path / "cache"))
    half = load_capture(d, CaptureOptions(image_scale=2, holdout="layout", normalize=False))
    a, b = held.train[0].camera, half.train[0].camera
    assert (b.width, b.height) == (round(a.width / 2), round(a.height / 2))
    assert np.allclose(b.K[0], a.K[0] * b.width / a.width) and np.allclose(b.K[1], a.K[1] * b.height / a.height)
    assert np.array_equal(b.w2c, a.w2c) and b.time == a.time
    from benchmark.datasets.images import image_size

    assert image_size(half.train[0].image_path) == (b.width, b.height)
    assert image_size(half.test[0].image_path) == (half.test[0].camera.width, half.test[0].camera.height)


def test_scaled_files_are_premultiplied_area_averages_cached_by_source(tmp_path):
    import cv2

    from benchmark.captures.scaling import rescale, scaled_file
    from imagefiles import read_rgb

    # a 4x4 RGBA: left half opaque red, right half transparent (its colour, green, must not
    # bleed into the edge), one half-transparent white pixel
    img = np.zeros((4, 4, 4), np.uint8)
    img[:, :2] = (0, 0, 255, 255)  # BGRA red, opaque
    img[:, 2:] = (0, 255, 0, 0)  # green, fully transparent
    img[0, 0] = (255, 255, 255, 128)
    src = tmp_path / "a.png"
    cv2.imwrite(str(src), img)
    out = scaled_file(src, (2, 2), tmp_path / "cache")
    for bg in ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0)):
        want = cv2.resize(read_rgb(src, bg), (2, 2), interpolation=cv2.INTER_AREA)  # scaled composite
        assert np.allclose(read_rgb(out, bg), want, atol=2e-5)
    small = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert small.dtype == np.uint16 and small.shape == (2, 2, 4)
    assert small[1, 1, 3] == 0 and small[1, 0, 3] == 65535  # alpha kept
    # written once: the same source and size give the same file, a changed source another
    mtime = out.stat().st_mtime_ns
    assert scaled_file(src, (2, 2), tmp_path / "cache") == out and out.stat().st_mtime_ns == mtime
    cv2.imwrite(str(src), img[::-1])
    assert scaled_file(src, (2, 2), tmp_path / "cache") != out
    assert rescale([], 2.0) == []
