import dataclasses

import cv2
import numpy as np
import pytest

from trase.camera import Camera, CameraError, intrinsics, look_at


def _cam(**kw):
    base = {"K": intrinsics(100.0, 100.0, 40.0, 30.0), "w2c": np.eye(4), "width": 80, "height": 60}
    base.update(kw)
    return Camera(**base)


def test_pinhole_projection_by_hand():
    cam = _cam()
    uv, z = cam.project(np.array([[0.2, -0.1, 2.0]]))
    assert z[0] == 2.0
    assert uv[0] == pytest.approx([40 + 100 * 0.1, 30 - 100 * 0.05])


def test_behind_camera_is_nan_for_pinhole():
    uv, z = _cam().project(np.array([[0.0, 0.0, -1.0]]))
    assert z[0] < 0 and np.isnan(uv).all()


def test_nerfies_distortion_matches_opencv():
    rng = np.random.default_rng(0)
    w2c = look_at([0.3, -2.0, 0.5], [0, 0, 0])
    K = intrinsics(120.0, 120.0 * 1.01, 41.0, 29.0, skew=0.0)
    cam = _cam(K=K, w2c=w2c, radial=(0.05, -0.01, 0.002), tangential=(0.001, -0.002))
    pts = rng.normal(scale=0.3, size=(20, 3))
    uv, _ = cam.project(pts)
    rvec, _ = cv2.Rodrigues(w2c[:3, :3])
    dist = np.array([0.05, -0.01, 0.001, -0.002, 0.002])
    ref, _ = cv2.projectPoints(pts, rvec, w2c[:3, 3], K, dist)
    np.testing.assert_allclose(uv, ref[:, 0], atol=1e-9)


def test_fisheye_matches_cv2_fisheye():
    rng = np.random.default_rng(1)
    w2c = look_at([0.0, -3.0, 0.2], [0, 0, 0])
    K = intrinsics(80.0, 80.0, 64.0, 48.0)
    cam = _cam(K=K, w2c=w2c, width=128, height=96, radial=(0.03, -0.004, 0.0), fisheye=True)
    pts = rng.normal(scale=1.0, size=(20, 3))
    uv, _ = cam.project(pts)
    rvec, _ = cv2.Rodrigues(w2c[:3, :3])
    ref, _ = cv2.fisheye.projectPoints(
        pts[None], rvec, w2c[:3, 3], K, np.array([0.03, -0.004, 0.0, 0.0])
    )
    np.testing.assert_allclose(uv, ref[0], atol=1e-8)


def test_unproject_inverts_project_and_scaled():
    cam = _cam(w2c=look_at([1.0, -2.0, 1.0], [0, 0, 0]))
    pts = np.array([[0.1, 0.2, 0.3], [-0.2, 0.0, 0.1]])
    uv, z = cam.project(pts)
    np.testing.assert_allclose(cam.unproject(uv, z), pts, atol=1e-12)
    half = cam.scaled(2)
    assert (half.width, half.height) == (40, 30)
    np.testing.assert_allclose(half.project(pts)[0], uv / 2, atol=1e-12)
    np.testing.assert_allclose(cam.center, [1.0, -2.0, 1.0], atol=1e-12)


def test_resized_maps_the_image_corners_onto_a_size_rounded_to_whole_pixels():
    cam = _cam(K=intrinsics(100.0, 90.0, 41.0, 29.0, skew=2.0), w2c=look_at([1.0, -2.0, 1.0], [0, 0, 0]))
    pts = np.array([[0.1, 0.2, 0.3], [-0.2, 0.0, 0.1]])
    uv, _ = cam.project(pts)
    small = cam.resized(round(80 / 2.75), round(60 / 2.75))  # 29 x 22 px: not 80 / 2.75 x 60 / 2.75
    assert (small.width, small.height) == (29, 22)
    np.testing.assert_allclose(small.project(pts)[0], uv * [29 / 80, 22 / 60], atol=1e-12)
    by_factor = cam.scaled(2.75)  # the same rounded size and the same corners
    assert (by_factor.width, by_factor.height) == (29, 22)
    np.testing.assert_allclose(by_factor.project(pts)[0], uv * [29 / 80, 22 / 60], atol=1e-12)


def test_look_at_up_is_screen_up():
    cam = _cam(w2c=look_at([0, -5, 0], [0, 0, 0]))
    uv_low, _ = cam.project(np.array([[0, 0, -1.0]]))
    uv_high, _ = cam.project(np.array([[0, 0, 1.0]]))
    assert uv_high[0, 1] < uv_low[0, 1]  # world +z is up on screen (smaller v)


def test_invalid_cameras_fail_clearly():
    with pytest.raises(CameraError, match="cam7: intrinsics or pose contain NaN"):
        _cam(name="cam7", w2c=np.full((4, 4), np.nan))
    with pytest.raises(CameraError, match="not a proper rotation"):
        _cam(w2c=np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(CameraError, match="K must be 3x3"):
        _cam(K=np.eye(2))
    with pytest.raises(CameraError, match="needs an undistorted pinhole"):
        _cam(fisheye=True).unproject(np.zeros((1, 2)), np.ones(1))


def test_dict_round_trip():
    cam = _cam(name="x", radial=(0.1, 0.0, 0.0), time=0.25)
    back = Camera.from_dict(cam.to_dict())
    assert back.to_dict() == cam.to_dict()
    assert dataclasses.replace(cam, time=0.5).time == 0.5


def test_near_plane_travels_with_the_camera():
    from trase.camera import NEAR_PLANE

    cam = _cam(name="x")
    assert cam.near == NEAR_PLANE and "near" not in cam.to_dict()  # the default: files and keys as before
    far = cam.with_near(0.2)
    assert far.near == 0.2 and far.to_dict()["near"] == 0.2
    assert Camera.from_dict(far.to_dict()).near == 0.2
    assert far.scaled(2).near == 0.2 and far.with_time(0.5).near == 0.2 and far.undistorted().near == 0.2
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(CameraError, match="x: near plane must be a positive number"):
            cam.with_near(bad)
