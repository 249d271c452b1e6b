"""Technicolor light field: ``<Scene>_undist_<frame:05d>_<cam:02d>.png`` + ``cameras_parameters.txt``.

``cameras_parameters.txt``: a header line, then one row per camera of the 4x4 rig,
``f cu cv ar sk qw qx qy qz tx ty tz``: focal length, principal point, aspect ratio, skew,
and the COLMAP world-to-camera rotation (unit quaternion, w first) and translation. The images
are already undistorted by the publisher; their principal point is off-centre.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from benchmark.datasets.errors import fail
from benchmark.datasets.images import image_size, read_image
from trase.camera import Camera, CameraError

_FILE = re.compile(r"^(?P<scene>.+)_undist_(?P<frame>\d{5})_(?P<cam>\d{2})\.png$")


def camera_name(index: int) -> str:
    return f"cam{index:02d}"


def read_cameras_parameters(path: Path | str, width: int, height: int) -> list[Camera]:
    """``cameras_parameters.txt`` -> native pinhole cameras cam00, cam01, ... (file row order)."""
    path = Path(path)
    if not path.is_file():
        raise fail(path, "missing cameras_parameters.txt")
    lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    if len(lines) < 2:
        raise fail(path, "no camera rows after the header")
    cams = []
    for i, line in enumerate(lines[1:]):
        try:
            v = np.array([float(x) for x in line.split()], dtype=np.float64)
        except ValueError:
            raise fail(path, f"row {i + 1} is not numeric: {line.strip()!r}") from None
        if v.size != 12:
            raise fail(path, f"row {i + 1} has {v.size} values, expected 12 (f cu cv ar sk qw qx qy qz tx ty tz)")
        if not np.isfinite(v).all():
            raise fail(path, f"row {i + 1} contains NaN or Inf")
        f, cu, cv, ar, sk = v[:5]
        q = v[5:9]
        if abs(np.linalg.norm(q) - 1.0) > 1e-3:
            raise fail(path, f"row {i + 1}: quaternion is not unit length (|q| = {np.linalg.norm(q):.4f})")
        w2c = np.eye(4)
        w2c[:3, :3] = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
        w2c[:3, 3] = v[9:12]
        K = np.array([[f, sk, cu], [0.0, f * ar, cv], [0.0, 0.0, 1.0]])
        try:
            cams.append(Camera(K=K, w2c=w2c, width=width, height=height, name=camera_name(i)))
        except CameraError as exc:
            raise fail(path, f"row {i + 1}: {exc}") from None
    return cams


class TechnicolorSource:
    """Raw Technicolor sequence: native cameras and the publisher's undistorted PNGs."""

    def __init__(self, scene_dir: Path):
        self.dir = scene_dir
        self.files: dict[tuple[str, int], Path] = {}
        self.repaired: list[str] = []
        for p in scene_dir.glob("*_undist_*.png"):
            m = _FILE.match(p.name)
            if m:
                self.files[(camera_name(int(m.group("cam"))), int(m.group("frame")))] = p
        if not self.files:
            raise fail(scene_dir, "no <Scene>_undist_<frame>_<cam>.png images")
        first = self.files[min(self.files)]
        W, H = image_size(first)
        params = scene_dir / "cameras_parameters.txt"
        self.cameras = read_cameras_parameters(params, W, H)
        cams_in_files = {c for c, _ in self.files}
        names = {c.name for c in self.cameras}
        if cams_in_files != names:
            raise fail(params, f"{len(names)} camera rows but images for {len(cams_in_files)} cameras")

    def frames(self, camera: str, frames: list[int]):
        for fr in frames:
            p = self.files.get((camera, fr))
            if p is None:
                raise fail(self.dir, f"missing image for camera {camera} frame {fr} (*_undist_{fr:05d}_{camera[3:]}.png)")
            img = self._read(p, camera, fr)
            cam = next(c for c in self.cameras if c.name == camera)
            if (img.shape[1], img.shape[0]) != (cam.width, cam.height):
                raise fail(p, f"image is {img.shape[1]}x{img.shape[0]} but the rig's images are {cam.width}x{cam.height}")
            yield fr, img

    def _read(self, p: Path, camera: str, frame: int) -> np.ndarray:
        """Read one PNG. A truncated file (the publisher's Birthday_undist_00173_09.png is one)
        is completed from the previous frame of the same camera where its pixels are missing
        (black), as the public preprocessing does; repairs are listed in ``self.repaired``."""
        from PIL import Image, ImageFile, UnidentifiedImageError

        try:
            with Image.open(p) as im:
                im.load()
            return read_image(p)
        except UnidentifiedImageError:  # not a truncated PNG: not an image at all
            raise fail(p, "cannot read image (not a PNG file)") from None
        except (OSError, SyntaxError):
            pass
        prev = self.files.get((camera, frame - 1))
        if prev is None:
            raise fail(p, "truncated image and no previous frame to complete it from")
        old = ImageFile.LOAD_TRUNCATED_IMAGES
        ImageFile.LOAD_TRUNCATED_IMAGES = True
        try:
            with Image.open(p) as im:
                part = np.asarray(im.convert("RGB"))[..., ::-1]  # RGB -> BGR
        finally:
            ImageFile.LOAD_TRUNCATED_IMAGES = old
        ref = read_image(prev)
        if ref.shape != part.shape:
            raise fail(p, "truncated image and its previous frame differ in size")
        self.repaired.append(p.name)
        return np.where(part == 0, ref, part)

    def depth_range(self) -> None:
        return None
