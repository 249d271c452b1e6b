"""Writing an edited scene so it reloads with ``trase.checkpoint.load_model``.

    <out>/model/        point_cloud/iteration_N/point_cloud.ply + deform/iteration_N/...
    <out>/segmentation/ clusters.npy, keep.npy (what selections need after reloading)

A model whose motion is still one Deformable-3DGS network (removal, extraction, recolouring
of a trained model) is written exactly in the public layout (deform.pth), so the public code
opens it too. A composition's motion (several networks, rigid transforms, time offsets) has no
form in that layout; it is baked into per-time offsets at the given times
(``deform_table.npz``, linear in between), which ``load_model`` reads and the public code
does not.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from trase.checkpoint import load_model, save_model
from trase.deformation import DeformMLP, TabulatedDeformation, deformed
from trase.edit.model import EditableModel, EditError
from trase.gaussians import GaussianModel
from trase.io import atomic_directory

ITERATION = 1  # the iteration number an edited model is saved under


@torch.no_grad()
def bake(model: EditableModel, times: Sequence[float]) -> TabulatedDeformation:
    """The model's motion as offsets from its canonical gaussians at ``times`` (exact there)."""
    ts = np.unique(np.asarray(list(times), dtype=np.float64))
    if ts.size == 0 or not np.isfinite(ts).all():
        raise EditError("bake: give at least one finite time to tabulate the motion at")
    g = model.gaussians
    xyz, q0, s0 = g.means.detach(), g.rotations.detach(), g.scales.detach()
    d_xyz, d_rot, d_scale = [], [], []
    for t in ts:
        m, q, s = deformed(g, model.deformation, float(t))
        d_xyz.append(m - xyz)
        d_rot.append(q - q0)
        d_scale.append(s - s0)
    return TabulatedDeformation(ts, torch.stack(d_xyz), torch.stack(d_rot), torch.stack(d_scale))


def save_edited(model: EditableModel, out_dir: str | Path, times: Sequence[float] | None = None) -> Path:
    """Write ``model`` (see the module doc); ``times`` are needed when its motion must be baked."""
    out = Path(out_dir)
    from trase.static_gaussians import PartlyStaticDeformation

    deformation = model.deformation
    savable = (DeformMLP, TabulatedDeformation, PartlyStaticDeformation)  # row-aligned or row-free: as they are
    if deformation is not None and not isinstance(deformation, savable):
        if times is None:
            raise EditError("this edited scene's motion (a composition) must be tabulated: give the times to bake")
        deformation = bake(model, times)
    with atomic_directory(out / "model") as d:
        save_model(d, model.gaussians, deformation, ITERATION)
    with atomic_directory(out / "segmentation") as d:
        np.save(d / "clusters.npy", model.labels)
        np.save(d / "keep.npy", model.keep)
    return out


def load_edited(out_dir: str | Path) -> EditableModel:
    """An ``EditableModel`` from a ``save_edited`` folder."""
    out = Path(out_dir)
    seg = out / "segmentation"
    for need in (out / "model", seg / "clusters.npy", seg / "keep.npy"):
        if not need.exists():
            raise EditError(f"{need}: not found (not an edited scene folder?)")
    g, deformation = load_model(out / "model")
    return EditableModel(g, deformation, np.load(seg / "clusters.npy"), np.load(seg / "keep.npy"))


@torch.no_grad()
def export_object_ply(model: EditableModel, selection: np.ndarray, path: str | Path,
                      time: float | None = None) -> Path:
    """The selected gaussians as one 3DGS PLY (what 3DGS viewers open): canonical, or as they
    stand at ``time`` (their deformation applied and dropped)."""
    sel = model.check_selection(selection)
    if not sel.any():
        raise EditError(f"{path}: the selection is empty, nothing to export")
    part = model.subset(sel)
    g = part.gaussians
    if time is not None and part.deformation is not None:
        m, q, s = deformed(g, part.deformation, float(time))
        g = GaussianModel(m, torch.log(s), q, g.opacity_logits, g.sh, g.features, g.active_sh_degree)
    g.save_ply(Path(path))
    return Path(path)
