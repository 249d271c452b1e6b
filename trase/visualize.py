"""Pictures of a (possibly edited) scene at a camera: the render modes of ``render`` and ``view``.

One rasterisation per picture gives every mode: colour from the SH, and as rendered features
the cluster palette (3), the selection (1) and a 3-component PCA of the learned features (3),
plus depth. Modes:

* ``rgb``: the scene's colour;
* ``depth``: expected depth, turbo colour map over the 2nd-98th percentile of covered pixels
  (alpha > 0.2);
* ``clusters``: each cluster's palette colour, composited like colour;
* ``selection``: colour with the selected gaussians' visible share tinted (share >= 0.5);
* ``pca``: the features' first three principal components as RGB (needs learned features).
"""

from __future__ import annotations

import copy

import numpy as np
import torch

from trase.camera import Camera
from trase.deformation import deformed

MODES = ("rgb", "depth", "clusters", "selection", "pca")
SELECTION_TINT = np.array([1.0, 0.25, 0.1], np.float32)


class VisualizeError(ValueError):
    user_facing = True


def cluster_colours(labels: np.ndarray, seed: int = 0) -> np.ndarray:
    """[N] cluster ids (-1: none, grey) -> [N, 3] float32 RGB in [0, 1]: a fixed random colour
    per cluster, the same for a cluster id in every picture of a run."""
    labels = np.asarray(labels, np.int64).reshape(-1)
    rng = np.random.default_rng(seed)
    palette = rng.uniform(0.15, 1.0, size=(int(labels.max()) + 2 if labels.size else 1, 3))
    return np.where(labels[:, None] >= 0, palette[np.clip(labels, 0, None)], 0.3).astype(np.float32)


def feature_pca(features: np.ndarray) -> np.ndarray:
    """[N, D] -> [N, 3] in [0, 1]: the first three principal components, each mapped from its
    1st-99th percentile range (a scene-wide colouring, stable across views and times)."""
    from sklearn.decomposition import PCA

    f = np.asarray(features, dtype=np.float32)
    if f.ndim != 2 or f.shape[0] < 3 or f.shape[1] < 3:
        raise VisualizeError(f"pca mode needs learned features [N >= 3, D >= 3], got {f.shape}")
    comps = PCA(n_components=3, random_state=0).fit_transform(f)
    lo, hi = np.percentile(comps, 1, axis=0), np.percentile(comps, 99, axis=0)
    return np.clip((comps - lo) / np.maximum(hi - lo, 1e-8), 0.0, 1.0).astype(np.float32)


class Painter:
    """Renders the modes of one model; per-gaussian colourings are computed once."""

    def __init__(self, model, selection: np.ndarray | None = None, device: str = "cpu") -> None:
        """``device``: where the scene is drawn: "cpu" (numba kernels) or "cuda" (the
        rasterizer's gsplat backend, which needs gsplat and a GPU)."""
        from trase.devices import gsplat_missing

        self.device = resolve_device(device)
        why = gsplat_missing(self.device)
        if why:
            raise VisualizeError(f"{why}; or draw on the cpu")
        self.model = model
        g = model.gaussians
        self._gaussians = g if self.device.type == "cpu" else g.copy().to(self.device)
        d = model.deformation
        # copies on the GPU: the model's own stay on the CPU for clicks and edits
        self._deformation = d if d is None or self.device.type == "cpu" else copy.deepcopy(d).to(self.device)
        self._clusters = torch.from_numpy(cluster_colours(model.labels)).to(self.device)  # [N, 3]
        self._pca: torch.Tensor | None = None  # [N, 3], computed on the first pca picture
        self.set_selection(selection)

    def set_selection(self, selection: np.ndarray | None) -> None:
        n = self.model.num_gaussians
        sel = np.zeros(n, bool) if selection is None else self.model.check_selection(selection)
        self._selection = torch.from_numpy(sel.astype(np.float32))[:, None].to(self.device)  # [N, 1]

    @torch.no_grad()
    def render(self, camera: Camera, mode: str = "rgb") -> np.ndarray:
        """[H, W, 3] uint8 picture of ``mode`` at camera (and camera.time)."""
        from trase.render import rasterize

        if mode not in MODES:
            raise VisualizeError(f"unknown render mode {mode!r}; choose one of {', '.join(MODES)}")
        if mode == "pca" and self._pca is None:
            feats = self.model.gaussians.features
            if feats is None:
                raise VisualizeError("pca mode needs learned features; this model has none")
            self._pca = torch.from_numpy(feature_pca(feats.detach().cpu().numpy())).to(self.device)
        g = self._gaussians
        H, W = camera.height, camera.width
        if g.num_gaussians == 0:
            return np.zeros((H, W, 3), np.uint8)
        m, q, s = deformed(g, self._deformation, float(camera.time))
        extra = {"clusters": self._clusters, "selection": self._selection, "pca": self._pca}.get(mode)
        out = rasterize(m, q, s, g.opacities, camera, colors=g.sh_for_render(), sh_degree=g.active_sh_degree,
                        features=extra)
        host = lambda t: t.detach().cpu().numpy()
        rgb = host(out.color)
        alpha = host(out.alpha)
        if mode in ("clusters", "pca"):
            img = host(out.features)
        elif mode == "selection":
            share = host(out.features)[..., 0]
            img = np.where((share >= 0.5)[..., None], 0.45 * rgb + 0.55 * SELECTION_TINT, rgb)
        elif mode == "depth":
            img = depth_colors(host(out.depth), alpha)
        else:
            img = rgb
        return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def resolve_device(device: str) -> torch.device:
    """trase.devices.resolve_device, its errors as VisualizeError."""
    from trase.devices import DeviceError
    from trase.devices import resolve_device as resolve

    try:
        return resolve(device)
    except DeviceError as exc:
        raise VisualizeError(str(exc)) from None


def depth_colors(depth: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """[H, W] depth -> [H, W, 3] turbo colours (near = warm), black where alpha < 0.2 (the
    expected depth of nearly empty pixels is noise)."""
    from matplotlib import colormaps

    covered = alpha > 0.2
    if not covered.any():
        return np.zeros(depth.shape + (3,), np.float32)
    lo, hi = np.percentile(depth[covered], [2, 98])
    x = 1.0 - np.clip((depth - lo) / max(hi - lo, 1e-8), 0.0, 1.0)
    img = colormaps["turbo"](x)[..., :3].astype(np.float32)
    return np.where(covered[..., None], img, 0.0)


def orbit_cameras(anchor: Camera, centre: np.ndarray, n: int, degrees: float = 30.0,
                  times: np.ndarray | None = None) -> list[Camera]:
    """``n`` cameras on an arc of ``degrees`` around ``centre`` (about the anchor camera's up
    axis), each looking at it; the anchor's intrinsics and near plane, times 0..1 unless given."""
    from scipy.spatial.transform import Rotation

    from trase.camera import look_at

    c2w = anchor.c2w
    up = -c2w[:3, 1]  # OpenCV: y points down in the image
    eye0 = c2w[:3, 3] - centre
    ts = np.linspace(0.0, 1.0, n) if times is None else np.asarray(times, dtype=np.float64)
    angles = np.linspace(-degrees / 2, degrees / 2, n) if n > 1 else np.zeros(1)
    cams = []
    for k, (a, t) in enumerate(zip(angles, ts)):
        eye = centre + Rotation.from_rotvec(np.deg2rad(a) * up / np.linalg.norm(up)).apply(eye0)
        cams.append(Camera(anchor.K, look_at(eye, centre, up), anchor.width, anchor.height, time=float(t),
                           name=f"orbit/{k:04d}", near=anchor.near))
    return cams


def look_centre(cameras: list[Camera]) -> np.ndarray:
    """[3] the point nearest to all cameras' optical axes (least squares): where they look."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for cam in cameras:
        c2w = cam.c2w
        o, d = c2w[:3, 3], c2w[:3, 2] / np.linalg.norm(c2w[:3, 2])
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ o
    if np.linalg.matrix_rank(A) < 3:  # parallel axes (one camera, or a straight rig): 1 unit ahead
        c2w = cameras[0].c2w
        return c2w[:3, 3] + c2w[:3, 2]
    return np.linalg.solve(A, b)


__all__ = [
    "MODES",
    "Painter",
    "VisualizeError",
    "cluster_colours",
    "depth_colors",
    "feature_pca",
    "look_centre",
    "orbit_cameras",
    "resolve_device",
]
