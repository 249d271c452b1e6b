"""From a publisher's native camera to the benchmark's training camera, and the image warp
between them. The one implementation that ``prepare`` and every multi-view loader share.

Per format (the resolution/principal-point conventions the ground truth was drawn in):

* neu3d: pinhole, principal point at the centre; downscale 2 with area averaging.
* technicolor: downscale 2, then translate the image so the principal point sits at the
  image centre (bilinear, zero border), as the public preprocessing does.
* immersive: downscale 2 (area), then undistort the equidistant fisheye to a pinhole camera
  whose focal length is OpenCV's ``estimateNewCameraMatrixForUndistortRectify`` (balance 0)
  and whose principal point is the image centre. The resampling map is built from
  ``Camera.project`` (pixel centres at i + 0.5), bilinear, reflected border.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from benchmark.datasets.registry import DatasetSpec
from trase.camera import Camera


@dataclasses.dataclass
class Rectifier:
    native: Camera  # publisher's camera at native resolution, full lens model
    camera: Camera  # pinhole at training resolution
    kind: str  # "resize", "shift" or "fisheye"
    _maps: tuple[np.ndarray, np.ndarray] | None = None

    def __call__(self, img: np.ndarray) -> np.ndarray:
        """[H0, W0, 3] native image -> [H, W, 3] training image."""
        import cv2

        W, H = self.camera.width, self.camera.height
        small = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA) if img.shape[:2] != (H, W) else img
        if self.kind == "resize":
            return small
        if self.kind == "shift":
            scaled = self.native.scaled(self._factor())
            dx, dy = self.camera.cx - scaled.cx, self.camera.cy - scaled.cy
            M = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]], dtype=np.float32)
            return cv2.warpAffine(small, M, (W, H), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        if self._maps is None:
            self._maps = _fisheye_maps(self.native.scaled(self._factor()), self.camera)
        return cv2.remap(small, self._maps[0], self._maps[1], interpolation=cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REFLECT_101)

    def _factor(self) -> float:
        return self.native.width / self.camera.width


def make_rectifier(spec: DatasetSpec, native: Camera) -> Rectifier:
    """The training camera of ``native`` for benchmark ``spec`` and the warp that goes with it."""
    scaled = native.scaled(spec.downscale)
    if spec.format == "neu3d":
        if not native.is_pinhole:
            raise ValueError(f"{native.name}: Neu3D cameras are pinhole")
        return Rectifier(native, scaled, "resize")
    if spec.format == "technicolor":
        K = scaled.K.copy()
        K[0, 2], K[1, 2] = scaled.width / 2.0, scaled.height / 2.0
        return Rectifier(native, dataclasses.replace(scaled, K=K), "shift")
    if spec.format == "immersive":
        return Rectifier(native, _undistorted_fisheye_camera(scaled), "fisheye")
    raise ValueError(f"{spec.key}: no rectifier for format {spec.format}")


def _undistorted_fisheye_camera(fish: Camera) -> Camera:
    import cv2

    W, H = fish.width, fish.height
    K_cv = fish.K.copy()
    K_cv[0, 1] = 0.0
    K_cv[0, 2] -= 0.5  # OpenCV puts pixel centres at integers
    K_cv[1, 2] -= 0.5
    D = np.array([fish.radial[0], fish.radial[1], fish.radial[2], 0.0]).reshape(4, 1)
    new_K = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K_cv, D, (W, H), np.eye(3), balance=0.0)
    K = np.array([[new_K[0, 0], 0.0, W / 2.0], [0.0, new_K[1, 1], H / 2.0], [0.0, 0.0, 1.0]])
    return dataclasses.replace(fish, K=K, radial=(0.0, 0.0, 0.0), tangential=(0.0, 0.0), fisheye=False)


def _fisheye_maps(fish: Camera, pinhole: Camera) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap maps: for each target pixel centre, where the fisheye image sees its ray."""
    W, H = pinhole.width, pinhole.height
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    uv = np.stack([u.ravel(), v.ravel()], axis=1)
    rays = pinhole.pixel_rays(uv)  # [N, 3] camera space
    cam_only = dataclasses.replace(fish, w2c=np.eye(4))
    src, _ = cam_only.project(rays)  # [N, 2], corner convention
    mx = (src[:, 0] - 0.5).reshape(H, W).astype(np.float32)
    my = (src[:, 1] - 0.5).reshape(H, W).astype(np.float32)
    return mx, my
