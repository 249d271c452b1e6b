"""The structural walk of COLMAP .bin files: a whole model passes, every cut is caught."""

from __future__ import annotations

import struct

import pytest

from benchmark.captures.colmap_binary import binary_model_problem


def _point(pid: int, track: int) -> bytes:
    return struct.pack("<Q3d3Bd", pid, 0.1, 0.2, 0.3, 1, 2, 3, 0.5) + struct.pack("<Q", track) + b"\x00" * 8 * track


def _image(iid: int, name: bytes, n2d: int) -> bytes:
    return struct.pack("<I4d3dI", iid, 1, 0, 0, 0, 0, 0, 0, 1) + name + b"\x00" + struct.pack("<Q", n2d) + b"\x01" * 24 * n2d


def _model(tmp_path):
    d = tmp_path / "sparse"
    d.mkdir()
    (d / "points3D.bin").write_bytes(struct.pack("<Q", 3) + _point(1, 2) + _point(2, 0) + _point(3, 5))
    (d / "images.bin").write_bytes(struct.pack("<Q", 2) + _image(1, b"a.png", 3) + _image(2, b"b.png", 0))
    (d / "cameras.bin").write_bytes(struct.pack("<Q", 1) + struct.pack("<iiQQ4d", 1, 1, 64, 48, 50, 50, 32, 24))
    return d


def test_a_whole_model_passes(tmp_path, capture_dirs):
    assert binary_model_problem(_model(tmp_path)) is None
    assert binary_model_problem(capture_dirs["colmap"] / "sparse/0") is None  # written by pycolmap


@pytest.mark.parametrize("name", ["points3D.bin", "images.bin", "cameras.bin"])
def test_every_cut_is_caught(tmp_path, name):
    d = _model(tmp_path)
    data = (d / name).read_bytes()
    for cut in range(0, len(data) - 1, 7):
        (d / name).write_bytes(data[:cut])
        found = binary_model_problem(d)
        if name == "cameras.bin" and cut >= 8 + 24:  # only the fixed part of each camera is checked
            continue
        assert found is not None and found[0] == d / name and "truncated COLMAP file" in found[1], cut


def test_a_huge_declared_track_is_caught_without_reading_it(tmp_path):
    d = _model(tmp_path)
    (d / "points3D.bin").write_bytes(struct.pack("<Q", 1) + _point(1, 0)[:43] + struct.pack("<Q", 2**60))
    path, problem = binary_model_problem(d)
    assert path.name == "points3D.bin" and "track of point 0 of 1" in problem
