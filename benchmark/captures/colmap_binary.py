"""A structural check of COLMAP's binary model files before pycolmap reads them.

pycolmap trusts the counts inside a .bin file: a truncated points3D.bin or images.bin makes it
read past the end and size its arrays from garbage (measured: a 2-byte points3D.bin took
115 s and 15 GB before failing). This walk reads only the counts and record lengths and
says where a file ends early; it is linear in the file's records (about 1 s per million
points in Python, with no faster maintained reader that checks this).
"""

from __future__ import annotations

import struct
from pathlib import Path


def _walk_points3d(buf: bytes) -> str | None:
    (n,) = struct.unpack_from("<Q", buf, 0)
    pos = 8
    for i in range(n):
        # id u64, xyz 3 f64, rgb 3 u8, error f64, track length u64
        if pos + 43 + 8 > len(buf):
            return f"ends inside point {i} of {n}"
        (track,) = struct.unpack_from("<Q", buf, pos + 43)
        pos += 51 + 8 * track  # track: (image id i32, point2D index i32) per element
        if pos > len(buf):
            return f"ends inside the track of point {i} of {n}"
    return None


def _walk_images(buf: bytes) -> str | None:
    (n,) = struct.unpack_from("<Q", buf, 0)
    pos = 8
    for i in range(n):
        # id u32, qvec 4 f64, tvec 3 f64, camera id u32, name (NUL-terminated)
        pos += 4 + 56 + 4
        end = buf.find(b"\x00", pos)
        if pos > len(buf) or end < 0:
            return f"ends inside image {i} of {n}"
        pos = end + 1
        if pos + 8 > len(buf):
            return f"ends inside image {i} of {n}"
        (m,) = struct.unpack_from("<Q", buf, pos)
        pos += 8 + 24 * m  # points2D: x f64, y f64, point3D id i64
        if pos > len(buf):
            return f"ends inside the 2D points of image {i} of {n}"
    return None


def _walk_cameras(buf: bytes) -> str | None:
    (n,) = struct.unpack_from("<Q", buf, 0)
    if 8 + 24 * n > len(buf):  # id i32, model i32, width u64, height u64 (+ parameters)
        return f"holds {len(buf)} bytes, too few for the {n} cameras it declares"
    return None


WALKS = {"points3D.bin": _walk_points3d, "images.bin": _walk_images, "cameras.bin": _walk_cameras}


def binary_model_problem(sparse_dir: Path) -> tuple[Path, str] | None:
    """(file, what is wrong) for the first .bin file of the model that ends early, else None."""
    for name, walk in WALKS.items():
        path = Path(sparse_dir) / name
        if not path.is_file():
            continue
        buf = path.read_bytes()
        problem = "shorter than its 8-byte count" if len(buf) < 8 else walk(buf)
        if problem:
            return path, f"truncated COLMAP file: {problem}"
    return None
