"""Write learned features and clusters in forms the public TRASE code and its viewers read.

* ``point_cloud.ply``: the 3DGS attribute layout written by ``GaussianModel.save_ply`` with
  TRASE's ``gaussian_feats_{i}`` columns, plus (optional) the float column ``cls`` with cluster
  ids, which the public code's ``load_ply`` picks up as saved cluster indices.
* ``clusters.npy``: int64 [N] cluster id per gaussian (-1 never occurs: every gaussian is
  assigned); ``clusters.pt``: ``torch.save({'id': ndarray})``, the public GUI's
  ``load_clusters`` format; ``features.npy``: float32 [N, D].
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from trase.io import atomic_path, atomic_torch_save


def _atomic(path: Path, write) -> None:
    with atomic_path(path) as tmp:
        write(tmp)


def _save_npy(path: str, array: np.ndarray) -> None:
    with open(path, "wb") as fh:
        np.save(fh, array)


def export_ply(gaussians, features, path: str | Path, labels: np.ndarray | None = None) -> Path:
    """Gaussians with ``features`` [N, D] (and cluster ``labels`` [N] as column ``cls``)."""
    from plyfile import PlyData, PlyElement

    from trase.gaussians import GaussianModel

    path = Path(path)
    f = torch.as_tensor(np.asarray(features, dtype=np.float32))
    g = GaussianModel(gaussians.means.detach(), gaussians.log_scales.detach(), gaussians.quats.detach(),
                      gaussians.opacity_logits.detach(), gaussians.sh.detach(), f)
    g.save_ply(path)
    if labels is not None:
        labels = np.asarray(labels).reshape(-1)
        if labels.shape[0] != g.num_gaussians:
            raise ValueError(f"{path}: {labels.shape[0]} cluster labels for {g.num_gaussians} gaussians")
        ply = PlyData.read(str(path))
        v = ply["vertex"].data
        names = list(v.dtype.names) + ["cls"]
        rec = np.empty(len(v), dtype=[(n, "f4") for n in names])
        for n in v.dtype.names:
            rec[n] = v[n]
        rec["cls"] = labels.astype(np.float32)
        _atomic(path, lambda tmp: PlyData([PlyElement.describe(rec, "vertex")]).write(tmp))
    return path


def export_clusters(out_dir: str | Path, labels: np.ndarray, features=None) -> dict[str, Path]:
    """clusters.npy, clusters.pt (public GUI format) and optionally features.npy in out_dir."""
    out = Path(out_dir)
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    paths = {"clusters_npy": out / "clusters.npy", "clusters_pt": out / "clusters.pt"}
    _atomic(paths["clusters_npy"], lambda tmp: _save_npy(tmp, labels))
    atomic_torch_save({"id": labels}, paths["clusters_pt"])
    if features is not None:
        feats = np.asarray(features.detach().cpu() if torch.is_tensor(features) else features, dtype=np.float32)
        paths["features_npy"] = out / "features.npy"
        _atomic(paths["features_npy"], lambda tmp: _save_npy(tmp, feats))
    return paths
