"""The one image reader: its rule for 8/16-bit, gray and alpha, and its one-line errors."""

import cv2
import numpy as np
import pytest

from imagefiles import WHITE, ImageFileError, read_mask, read_rgb, read_rgb8


def _write(path, img):
    assert cv2.imwrite(str(path), img)
    return path


@pytest.fixture
def rgb8():
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)  # RGB


def test_8bit_rgb_comes_back_byte_for_byte(tmp_path, rgb8):
    p = _write(tmp_path / "a.png", rgb8[:, :, ::-1])  # OpenCV writes BGR
    assert np.array_equal(read_rgb8(p), rgb8)
    f = read_rgb(p)
    assert f.dtype == np.float32 and f.shape == (5, 7, 3)
    assert np.array_equal(f, rgb8.astype(np.float32) / np.float32(255))
    assert np.array_equal(np.round(f * 255).astype(np.uint8), rgb8)


def test_16bit_is_divided_by_65535_and_rounded_to_8bit(tmp_path):
    img = np.array([[[0, 257, 65535], [128, 32896, 65406]]], np.uint16)  # RGB
    p = _write(tmp_path / "a.png", img[:, :, ::-1])
    assert np.allclose(read_rgb(p), img / 65535.0, atol=1e-7)
    assert read_rgb8(p).tolist() == [[[0, 1, 255], [0, 128, 254]]]


def test_gray_becomes_three_equal_channels(tmp_path):
    g = np.arange(12, dtype=np.uint8).reshape(3, 4) * 20
    p = _write(tmp_path / "g.png", g)
    out = read_rgb8(p)
    assert out.shape == (3, 4, 3) and all(np.array_equal(out[:, :, c], g) for c in range(3))


def test_alpha_is_straight_and_composited_over_the_background(tmp_path):
    bgra = np.zeros((1, 3, 4), np.uint8)
    bgra[0, :, :3] = (10, 20, 200)  # B, G, R
    bgra[0, :, 3] = (255, 0, 51)  # opaque, transparent, 20%
    p = _write(tmp_path / "a.png", bgra)
    black = read_rgb(p)
    assert np.allclose(black[0, 0], np.array([200, 20, 10]) / 255)
    assert np.allclose(black[0, 1], 0)
    assert np.allclose(black[0, 2], 0.2 * np.array([200, 20, 10]) / 255, atol=1e-6)
    white = read_rgb(p, WHITE)
    assert np.allclose(white[0, 1], 1) and np.allclose(white[0, 2], 0.2 * np.array([200, 20, 10]) / 255 + 0.8)
    assert np.array_equal(read_rgb8(p, WHITE), np.round(white * 255).astype(np.uint8))


def test_a_mask_is_the_alpha_of_a_cut_out_else_its_non_zero_pixels(tmp_path):
    bgra = np.full((1, 3, 4), 255, np.uint8)
    bgra[0, :, 3] = (255, 127, 128)  # alpha >= 0.5 of 255: 128 in, 127 out
    assert read_mask(_write(tmp_path / "a.png", bgra)).tolist() == [[True, False, True]]
    gray = np.array([[0, 1, 255]], np.uint8)
    assert read_mask(_write(tmp_path / "g.png", gray)).tolist() == [[False, True, True]]
    colour = np.zeros((1, 2, 3), np.uint16)
    colour[0, 1, 2] = 7
    assert read_mask(_write(tmp_path / "c.png", colour)).tolist() == [[False, True]]


def test_mask_generation_and_reconstruction_see_the_same_picture(tmp_path):
    """An RGBA training image: the picture masks are cut from is the reconstruction's, rounded."""
    from trase.camera import Camera, intrinsics
    from trase.training_images import load_image

    rng = np.random.default_rng(1)
    bgra = rng.integers(0, 256, (6, 8, 4), dtype=np.uint8)
    p = _write(tmp_path / "a.png", bgra)
    cam = Camera(intrinsics(8, 8, 4, 3), np.eye(4), 8, 6)
    for bg in (np.zeros(3, np.float32), np.ones(3, np.float32)):
        trained = load_image(p, cam, bg)
        assert np.array_equal(np.round(trained * 255).astype(np.uint8), read_rgb8(p, bg))


def test_errors_are_one_line_and_name_the_file(tmp_path):
    with pytest.raises(ImageFileError, match=r"nope.png: image file not found"):
        read_rgb(tmp_path / "nope.png")
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not a png")
    with pytest.raises(ImageFileError, match=r"bad.png: cannot decode image"):
        read_rgb8(bad)
    f = _write(tmp_path / "f.tiff", np.zeros((2, 2, 3), np.float32))
    with pytest.raises(ImageFileError, match=r"f.tiff: unsupported sample type float32"):
        read_rgb(f)
    assert ImageFileError.user_facing
