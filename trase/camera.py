"""A calibrated camera at one moment: intrinsics, world-to-camera pose, lens model, time.

Conventions (every loader converts into these, the rasterizer and prompts assume them):

* Axes are OpenCV's: x right, y down, z forward (into the scene). ``w2c`` maps world points
  to camera points; depth is the camera-space z.
* Pixel coordinates are continuous with the image's top-left *corner* at (0, 0), so the
  centre of pixel (col i, row j) is (i + 0.5, j + 0.5) (COLMAP, nerfies and gsplat use the
  same). With this convention, downscaling by s is exactly ``uv / s`` and ``K[:2] / s``.
* ``K`` is 3x3 with any principal point, and may carry skew and a pixel aspect ratio
  (K = [[f, skew, cx], [0, f * aspect, cy], [0, 0, 1]]); it is applied to *distorted*
  normalised coordinates, as the nerfies camera model does.
* Lens: ``radial`` = (k1, k2, k3) and ``tangential`` = (p1, p2) for the nerfies/OpenCV
  pinhole model, or ``fisheye=True`` for the equidistant model of the Immersive dataset
  (theta = atan2(r, z), r_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6), same as
  cv2.fisheye with D = [k1, k2, k3, 0]).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

# the near plane of a camera that names none (view-space depth, scene units): renders through it
# draw nothing nearer. The cpu presets train with it; the public 3DGS rasterizer's is 0.2, which
# the paper preset trains with (ReconstructionConfig.near_plane), and a geometry is rendered with
# the plane it was trained with (benchmark: the scene's cameras carry it)
NEAR_PLANE = 0.01


class CameraError(ValueError):
    """An invalid camera; the message says which camera and what is wrong."""

    user_facing = True


@dataclasses.dataclass(frozen=True)
class Camera:
    K: np.ndarray  # [3, 3] float64
    w2c: np.ndarray  # [4, 4] float64, world -> camera (OpenCV axes)
    width: int
    height: int
    time: float = 0.0  # normalised to [0, 1]
    name: str = ""
    radial: tuple[float, float, float] = (0.0, 0.0, 0.0)  # k1, k2, k3
    tangential: tuple[float, float] = (0.0, 0.0)  # p1, p2
    fisheye: bool = False
    near: float = NEAR_PLANE  # renders through this camera draw nothing nearer (view-space depth)

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        w2c = np.asarray(self.w2c, dtype=np.float64)
        label = self.name or "camera"
        if K.shape != (3, 3):
            raise CameraError(f"{label}: K must be 3x3, got shape {K.shape}")
        if w2c.shape != (4, 4):
            raise CameraError(f"{label}: w2c must be 4x4, got shape {w2c.shape}")
        if not (np.isfinite(K).all() and np.isfinite(w2c).all()):
            raise CameraError(f"{label}: intrinsics or pose contain NaN or Inf")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise CameraError(f"{label}: focal length must be positive, got {K[0, 0]}, {K[1, 1]}")
        R = w2c[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
            raise CameraError(f"{label}: w2c rotation is not a proper rotation matrix")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CameraError(f"{label}: image size must be positive, got {self.width}x{self.height}")
        lens = tuple(self.radial) + tuple(self.tangential)
        if not all(math.isfinite(x) for x in lens) or len(self.radial) != 3 or len(self.tangential) != 2:
            raise CameraError(f"{label}: distortion must be 3 finite radial and 2 tangential terms")
        if not math.isfinite(self.time):
            raise CameraError(f"{label}: time is not finite")
        if not (math.isfinite(self.near) and self.near > 0):
            raise CameraError(f"{label}: near plane must be a positive number of scene units, got {self.near!r}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "w2c", w2c)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "radial", tuple(float(x) for x in self.radial))
        object.__setattr__(self, "tangential", tuple(float(x) for x in self.tangential))

    # -- derived quantities -------------------------------------------------------------
    @property
    def c2w(self) -> np.ndarray:
        """[4, 4] camera -> world."""
        R, t = self.w2c[:3, :3], self.w2c[:3, 3]
        out = np.eye(4)
        out[:3, :3] = R.T
        out[:3, 3] = -R.T @ t
        return out

    @property
    def center(self) -> np.ndarray:
        """[3] camera centre in world coordinates."""
        return self.c2w[:3, 3]

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def is_pinhole(self) -> bool:
        """True when projection is K @ (x/z, y/z, 1): no distortion, no fisheye."""
        return not self.fisheye and not any(self.radial) and not any(self.tangential)

    # -- projection ---------------------------------------------------------------------
    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """[N, 3] world -> [N, 3] camera coordinates."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return p @ self.w2c[:3, :3].T + self.w2c[:3, 3]

    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Normalised pinhole coordinates [N, 2] (x/z, y/z) -> distorted [N, 2].

        Only for non-fisheye cameras (fisheye distortion needs z for points behind 90 deg).
        """
        x, y = xy[:, 0], xy[:, 1]
        k1, k2, k3 = self.radial
        p1, p2 = self.tangential
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=1)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points [N, 3] -> (uv [N, 2] pixels, depth [N] camera z).

        Applies the full lens model. Points with depth <= 0 get uv = NaN for pinhole
        cameras; fisheye cameras project them while theta < pi.
        """
        pc = self.world_to_camera(points)
        z = pc[:, 2]
        if self.fisheye:
            r = np.hypot(pc[:, 0], pc[:, 1])
            theta = np.arctan2(r, z)
            k1, k2, k3 = self.radial
            t2 = theta * theta
            rd = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * k3)))
            with np.errstate(invalid="ignore", divide="ignore"):
                scale = np.where(r > 1e-12, rd / np.maximum(r, 1e-300), 1.0 / np.maximum(z, 1e-300))
            xd = pc[:, 0] * scale
            yd = pc[:, 1] * scale
        else:
            with np.errstate(invalid="ignore", divide="ignore"):
                xy = pc[:, :2] / z[:, None]
            xy[z <= 0] = np.nan
            d = self.distort(xy)
            xd, yd = d[:, 0], d[:, 1]
        K = self.K
        u = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
        v = K[1, 1] * yd + K[1, 2]
        return np.stack([u, v], axis=1), z

    def pixel_rays(self, uv: np.ndarray) -> np.ndarray:
        """Pixels [N, 2] -> unit ray directions [N, 3] in *camera* space (pinhole only)."""
        self._require_pinhole("pixel_rays")
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        y = (uv[:, 1] - self.cy) / self.fy
        x = (uv[:, 0] - self.cx - self.K[0, 1] * y) / self.fx
        d = np.stack([x, y, np.ones_like(x)], axis=1)
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def unproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Pixels [N, 2] with camera-space depth z [N] -> world points [N, 3] (pinhole only)."""
        self._require_pinhole("unproject")
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(depth, dtype=np.float64).reshape(-1)
        y = (uv[:, 1] - self.cy) / self.fy
        x = (uv[:, 0] - self.cx - self.K[0, 1] * y) / self.fx
        pc = np.stack([x * z, y * z, z], axis=1)
        c2w = self.c2w
        return pc @ c2w[:3, :3].T + c2w[:3, 3]

    def _require_pinhole(self, what: str) -> None:
        if not self.is_pinhole:
            raise CameraError(f"{self.name or 'camera'}: {what} needs an undistorted pinhole camera")

    # -- derived cameras ----------------------------------------------------------------
    def scaled(self, factor: float) -> Camera:
        """The same camera for an image downscaled by ``factor`` (2 -> half the size), the size
        rounded to whole pixels (``resized``)."""
        return self.resized(round(self.width / factor), round(self.height / factor))

    def resized(self, width: int, height: int) -> Camera:
        """The same camera for the image resampled to ``width`` x ``height`` px: each axis's row
        of K scaled by that axis's own ratio, so a size rounded to whole pixels still maps the
        image's corners onto the render's."""
        K = self.K.copy()
        K[0] *= width / self.width
        K[1] *= height / self.height
        return dataclasses.replace(self, K=K, width=int(width), height=int(height))

    def with_time(self, time: float) -> Camera:
        return dataclasses.replace(self, time=float(time))

    def with_near(self, near: float) -> Camera:
        """The same camera whose renders cull at ``near`` (the plane its geometry was trained with)."""
        return dataclasses.replace(self, near=float(near))

    def undistorted(self) -> Camera:
        """The pinhole camera (same K, pose, size) that undistorted images are resampled to."""
        return dataclasses.replace(self, radial=(0.0, 0.0, 0.0), tangential=(0.0, 0.0), fisheye=False)

    # -- serialisation ------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "K": self.K.tolist(),
            "w2c": self.w2c.tolist(),
            "width": self.width,
            "height": self.height,
            "time": self.time,
            "radial": list(self.radial),
            "tangential": list(self.tangential),
            "fisheye": self.fisheye,
            # only where it is not the default: files and keys of cameras at the default stay as before
            **({"near": self.near} if self.near != NEAR_PLANE else {}),
        }

    @classmethod
    def from_dict(cls, d: dict) -> Camera:
        return cls(
            K=np.asarray(d["K"], dtype=np.float64),
            w2c=np.asarray(d["w2c"], dtype=np.float64),
            width=int(d["width"]),
            height=int(d["height"]),
            time=float(d.get("time", 0.0)),
            name=str(d.get("name", "")),
            radial=tuple(d.get("radial", (0.0, 0.0, 0.0))),
            tangential=tuple(d.get("tangential", (0.0, 0.0))),
            fisheye=bool(d.get("fisheye", False)),
            near=float(d.get("near", NEAR_PLANE)),
        )


def intrinsics(fx: float, fy: float, cx: float, cy: float, skew: float = 0.0) -> np.ndarray:
    """[3, 3] pinhole intrinsics."""
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """[4, 4] OpenCV w2c for a camera at ``eye`` looking at ``target``; the image's -y axis
    (up on screen) is aligned with the world direction ``up`` (default +z)."""
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    down = -np.asarray(up, dtype=np.float64)
    x = np.cross(down, z)
    if np.linalg.norm(x) < 1e-9:
        raise CameraError("look_at: viewing direction is parallel to up")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world coordinates
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ eye
    return w2c
