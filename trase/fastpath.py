"""Frozen-geometry fast path for feature learning.

During feature training the geometry (canonical gaussians + deformation) is frozen, so for a
training view the compositing weights w[p, g] = alpha_g(p) T_g(p) never change: a rendered
feature is a fixed sparse linear map of the gaussian features. ``ViewWeights`` precomputes
that map once per view (CSR rows, only for pixels inside at least one mask: the only pixels
training samples) with ``trase.render.pixel_weights``, and renders the sampled pixels' features
by a sparse weighted gather (differentiable w.r.t. the features, no rasterization): fused numba
kernels on CPU float32/float64 (trase.gather.CsrRender; forward a per-row gather, backward a
column-blocked scatter), ``embedding_bag`` otherwise (``render_rows_reference``, which the
tests compare against; its CPU backward is ~5x slower).

Cache: one ``.npz`` per view under ``cache_dir`` (written atomically), keyed by a fingerprint
of the deformed geometry, the camera and the pixel set, so a stale file is never reused.
Memory: views stay in RAM in least-recently-used order up to ``max_bytes``; evicted views are
reloaded from disk. ``nbytes`` reports the footprint of each view.
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from trase.camera import Camera
from trase.deformation import deformed
from trase.gather import CsrRender, use_fused
from trase.io import atomic_path
from trase.render import PixelWeights, pixel_weights, rasterize

CACHE_VERSION = 1


class FastPathError(ValueError):
    user_facing = True


def frozen_geometry(gaussians, deformation, t: float):
    """(means [N,3], quats [N,4], scales [N,3], opacities [N]) at time t, detached."""
    with torch.no_grad():
        means, quats, scales = deformed(gaussians, deformation, t)
        return means.detach(), quats.detach(), scales.detach(), gaussians.opacities.detach()


def render_rows(pw: PixelWeights, rows: torch.Tensor, features: torch.Tensor, impl: str = "auto") -> torch.Tensor:
    """Rendered features [P, D] = sum_k w_k f_{g_k} over the CSR rows ``rows`` [P] of ``pw``.

    Cost O(contributors of the sampled pixels * D), independent of image size and of N.
    impl: 'auto' (fused numba kernels on CPU float32/float64, else the reference), 'fused' or
    'reference'."""
    if use_fused(features, impl, "render_rows"):
        if rows.shape[0] == 0:
            return features.new_zeros(0, features.shape[1])
        return CsrRender.apply(features, rows.to(torch.int64), pw.indptr, pw.indices, pw.weights)
    return render_rows_reference(pw, rows, features)


def render_rows_reference(pw: PixelWeights, rows: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
    """render_rows in plain torch: gather the sampled rows' entries, then a weighted
    ``embedding_bag`` sum per pixel."""
    P = rows.shape[0]
    D = features.shape[1]
    if P == 0:
        return features.new_zeros(0, D)
    starts = pw.indptr[rows]
    lengths = pw.indptr[rows + 1] - starts  # [P]
    total = int(lengths.sum())
    if total == 0:
        return features.new_zeros(P, D) + 0.0 * features.sum()
    first = torch.cumsum(lengths, 0) - lengths  # [P] offset of each row in the gathered list
    out_row = torch.repeat_interleave(torch.arange(P, device=rows.device), lengths)  # [nnz_s]
    pos = torch.arange(total, device=rows.device) - first[out_row] + starts[out_row]  # [nnz_s]
    return F.embedding_bag(pw.indices[pos], features, first, mode="sum",
                           per_sample_weights=pw.weights[pos].to(features.dtype))


def _to_device(pw: PixelWeights, device: torch.device) -> PixelWeights:
    """``pw`` on ``device`` (weights are computed on the CPU and cached on disk)."""
    if pw.indptr.device == device:
        return pw
    return PixelWeights(pixels=pw.pixels.to(device), indptr=pw.indptr.to(device),
                        indices=pw.indices.to(device), weights=pw.weights.to(device))


def _fingerprint(means, quats, scales, opacities, camera: Camera, pixels: np.ndarray, min_weight: float) -> str:
    h = hashlib.sha1()
    for t in (means, quats, scales, opacities):
        h.update(np.ascontiguousarray(t.cpu().numpy(), dtype=np.float32).tobytes())
    h.update(json.dumps(camera.to_dict(), sort_keys=True).encode())
    h.update(np.ascontiguousarray(pixels, dtype=np.int64).tobytes())
    h.update(f"{min_weight!r}/{CACHE_VERSION}".encode())
    return h.hexdigest()


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "view"


def _save_npz_atomic(path: Path, **arrays) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def pw_nbytes(pw: PixelWeights) -> int:
    return sum(int(t.numel() * t.element_size()) for t in (pw.pixels, pw.indptr, pw.indices, pw.weights))


@dataclasses.dataclass
class ViewInfo:
    name: str
    camera: Camera
    valid: np.ndarray  # [H, W] bool pixels the weights are computed for (inside >= 1 mask)


class ViewWeights:
    """Per-view sparse pixel -> gaussian weights, computed once, cached on disk and in RAM."""

    def __init__(
        self,
        gaussians,
        deformation,
        cache_dir: str | Path | None,
        min_weight: float = 0.0,
        max_bytes: int = 1 << 30,
        impl: str = "auto",
    ) -> None:
        self.impl = impl  # render_rows implementation: 'auto', 'fused' or 'reference'
        self.gaussians = gaussians
        self.deformation = deformation
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self.min_weight = float(min_weight)
        self.max_bytes = int(max_bytes)
        self._ram: collections.OrderedDict[int, PixelWeights] = collections.OrderedDict()
        self._ram_bytes = 0
        self._views: dict[int, ViewInfo] = {}
        self.nbytes: dict[str, int] = {}  # view name -> bytes of its weights
        self.hits = {"ram": 0, "disk": 0, "computed": 0}
        # view -> fingerprint of its frozen geometry, once known: the geometry is frozen for
        # this object's life, so a view reloaded from disk is not deformed again (a network
        # pass over every gaussian) just to check its file
        self._fingerprints: dict[int, str] = {}

    def register(self, key: int, name: str, camera: Camera, valid: np.ndarray) -> None:
        """Declare view ``key``: its camera (at mask resolution) and the pixels to cover."""
        valid = np.asarray(valid, dtype=bool)
        if valid.shape != (camera.height, camera.width):
            raise FastPathError(
                f"view {name}: mask size {valid.shape[1]}x{valid.shape[0]} differs from camera "
                f"{camera.width}x{camera.height}"
            )
        self._views[key] = ViewInfo(name, camera, valid)

    def _path(self, info: ViewInfo) -> Path | None:
        return None if self.cache_dir is None else self.cache_dir / f"{_safe_name(info.name)}.npz"

    def _compute_or_load(self, key: int) -> PixelWeights:
        info = self._views[key]
        pixels = np.flatnonzero(info.valid.reshape(-1)).astype(np.int64)  # ascending
        fp, geometry = self._fingerprints.get(key), None
        if fp is None:  # the first time this view is asked for in this run
            geometry = frozen_geometry(self.gaussians, self.deformation, info.camera.time)
            fp = _fingerprint(*geometry, info.camera, pixels, self.min_weight)
        path = self._path(info)
        if path is not None and path.is_file():
            try:
                with np.load(path, allow_pickle=False) as z:
                    if str(z["fingerprint"]) == fp:
                        self.hits["disk"] += 1
                        self._fingerprints[key] = fp
                        return PixelWeights(
                            pixels=torch.from_numpy(z["pixels"]),
                            indptr=torch.from_numpy(z["indptr"]),
                            indices=torch.from_numpy(z["indices"]),
                            weights=torch.from_numpy(z["weights"]),
                        )
            except (OSError, ValueError, KeyError):
                pass  # unreadable or stale cache file: recompute and overwrite
        if geometry is None:  # known view whose file went missing or bad: deform it again
            geometry = frozen_geometry(self.gaussians, self.deformation, info.camera.time)
        pw = pixel_weights(*geometry, info.camera, pixels=torch.from_numpy(pixels), min_weight=self.min_weight)
        self._fingerprints[key] = fp
        self.hits["computed"] += 1
        if path is not None:
            _save_npz_atomic(
                path, fingerprint=np.array(fp), pixels=pw.pixels.cpu().numpy(),
                indptr=pw.indptr.cpu().numpy(), indices=pw.indices.cpu().numpy(),
                weights=pw.weights.cpu().numpy(),
            )
        return pw

    def get(self, key: int) -> PixelWeights:
        if key in self._ram:
            self._ram.move_to_end(key)
            self.hits["ram"] += 1
            return self._ram[key]
        if key not in self._views:
            raise FastPathError(f"view {key} was not registered with the fast path")
        pw = _to_device(self._compute_or_load(key), self.gaussians.means.device)
        nb = pw_nbytes(pw)
        self.nbytes[self._views[key].name] = nb
        self._ram[key] = pw
        self._ram_bytes += nb
        while self._ram_bytes > self.max_bytes and len(self._ram) > 1:
            _, old = self._ram.popitem(last=False)
            self._ram_bytes -= pw_nbytes(old)
        return pw

    def prepare_all(self, progress: Callable[[int], None] | None = None) -> None:
        """Compute (or load) every registered view once, so the cache is warm."""
        for key in list(self._views):
            self.get(key)
            if progress is not None:
                progress(key)

    def render(self, key: int, features: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
        """features [N, D] -> [P, D] rendered at linear pixel ids ``pixels`` [P] of view key.

        Every pixel must lie inside the registered valid region."""
        pw = self.get(key)
        pix = torch.as_tensor(pixels, dtype=torch.int64).reshape(-1).to(pw.pixels.device).contiguous()
        rows = torch.searchsorted(pw.pixels, pix)
        rows_c = rows.clamp_max(max(len(pw.pixels) - 1, 0))
        if len(pix) and (len(pw.pixels) == 0 or not torch.equal(pw.pixels[rows_c], pix)):
            raise FastPathError(f"view {self._views[key].name}: sampled pixels outside the precomputed mask region")
        return render_rows(pw, rows_c, features, self.impl)

    def stats(self) -> dict:
        vals = list(self.nbytes.values())
        return {
            "path": "fastpath",
            "views": len(vals),
            "bytes_per_view_mean": float(np.mean(vals)) if vals else 0.0,
            "bytes_per_view_max": int(max(vals)) if vals else 0,
            "bytes_total": int(sum(vals)),
            "ram_bytes": int(self._ram_bytes),
            "max_bytes": self.max_bytes,
            "min_weight": self.min_weight,
            **{f"hits_{k}": v for k, v in self.hits.items()},
        }


class RasterizerPath:
    """The fallback: rasterize the full feature image at the frozen geometry every step."""

    def __init__(self, gaussians, deformation, backend: str = "auto") -> None:
        self.gaussians = gaussians
        self.deformation = deformation
        self.backend = backend
        self._views: dict[int, ViewInfo] = {}

    def register(self, key: int, name: str, camera: Camera, valid: np.ndarray) -> None:
        self._views[key] = ViewInfo(name, camera, np.asarray(valid, bool))

    def render(self, key: int, features: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
        info = self._views[key]
        means, quats, scales, opac = frozen_geometry(self.gaussians, self.deformation, info.camera.time)
        out = rasterize(means, quats, scales, opac, info.camera, features=features, backend=self.backend)
        D = features.shape[1]
        return out.features.reshape(-1, D)[torch.as_tensor(pixels, dtype=torch.int64).to(features.device)]

    def stats(self) -> dict:
        return {"path": "rasterizer", "views": len(self._views), "backend": self.backend}

