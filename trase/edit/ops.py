"""The edits: remove, extract, recolour a selection; compose parts of several models."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from trase.edit.model import EditableModel, EditError, subset_deformation
from trase.edit.rigid import (
    RigidTransform,
    StaticDeformation,
    TransformedDeformation,
    transform_gaussians,
)
from trase.gaussians import SH_C0, GaussianModel, rgb_to_sh_dc


def remove(model: EditableModel, selection: np.ndarray) -> EditableModel:
    """The model without the selected gaussians."""
    return model.subset(~model.check_selection(selection))


def extract(model: EditableModel, selection: np.ndarray) -> EditableModel:
    """Only the selected gaussians."""
    return model.subset(model.check_selection(selection))


def recolor(model: EditableModel, selection: np.ndarray, rgb=None, shift=None) -> EditableModel:
    """Set the selection's colour to ``rgb`` (3 values in [0, 1]; view-dependent terms
    dropped, so it reads as a flat paint) or add ``shift`` (3 values in [-1, 1]) to its
    view-independent colour. Exactly one of the two."""
    sel = model.check_selection(selection)
    if (rgb is None) == (shift is None):
        raise EditError("recolor: give exactly one of rgb (set) or shift (add)")
    value = np.asarray(rgb if rgb is not None else shift, dtype=np.float64).reshape(-1)
    lo = 0.0 if rgb is not None else -1.0
    if value.shape != (3,) or not np.isfinite(value).all() or value.min() < lo or value.max() > 1.0:
        what = "rgb" if rgb is not None else "shift"
        raise EditError(f"recolor: {what} must be 3 numbers in [{lo:g}, 1], got {value.tolist()}")
    g = model.gaussians.copy()
    idx = torch.from_numpy(np.flatnonzero(sel))
    with torch.no_grad():
        if rgb is not None:
            g.sh_dc[idx, 0] = torch.as_tensor(rgb_to_sh_dc(value), dtype=g.sh_dc.dtype)
            g.sh_rest[idx] = 0.0
        else:
            g.sh_dc[idx, 0] += torch.as_tensor(value / SH_C0, dtype=g.sh_dc.dtype)
    return EditableModel(g, model.deformation, model.labels.copy(), model.keep.copy())


class ConcatDeformation(nn.Module):
    """Deformations of consecutive blocks of gaussians, each evaluated on its own rows."""

    def __init__(self, parts: list, sizes: list[int]) -> None:
        super().__init__()
        if len(parts) != len(sizes):
            raise ValueError("ConcatDeformation: one size per part")
        self.parts = nn.ModuleList([p if p is not None else StaticDeformation() for p in parts])
        self.sizes = [int(s) for s in sizes]
        # networks apply their offsets by one scale rule each (trase.deformation.offset_scales);
        # a table of final offsets or a static part fits either
        rules = {getattr(p, "scale_rule", None) for p in parts} - {None}
        if len(rules) > 1:
            raise ValueError("ConcatDeformation: the parts' networks apply scale offsets by different rules "
                             f"({', '.join(sorted(rules))}); save each part (which tabulates its motion) first")
        self.scale_rule = rules.pop() if rules else None

    def forward(self, xyz: torch.Tensor, t):
        if xyz.shape[0] != sum(self.sizes):
            raise ValueError(f"ConcatDeformation holds {sum(self.sizes)} gaussians, got xyz for {xyz.shape[0]}")
        outs = [part(block, t) for part, block in zip(self.parts, torch.split(xyz, self.sizes))]
        return tuple(torch.cat([o[k] for o in outs], dim=0) for k in range(3))

    def rows(self, mask: torch.Tensor):
        parts, sizes = [], []
        for part, m in zip(self.parts, torch.split(mask, self.sizes)):
            if bool(m.any()):
                parts.append(subset_deformation(part, m.numpy()))
                sizes.append(int(m.sum()))
        return ConcatDeformation(parts, sizes)


def _concat_gaussians(gs: list[GaussianModel]) -> GaussianModel:
    """One model of all gaussians; SH padded with zeros to the highest degree; features kept
    only when every part has them with one width."""
    deg = max(g.max_sh_degree for g in gs)
    K = (deg + 1) ** 2
    sh = [torch.cat([g.sh.detach(), g.sh.new_zeros(g.num_gaussians, K - g.sh.shape[1], 3)], 1) for g in gs]
    dims = {None if g.features is None else int(g.features.shape[1]) for g in gs}
    feats = torch.cat([g.features.detach() for g in gs]) if len(dims) == 1 and None not in dims else None
    cat = lambda name: torch.cat([getattr(g, name).detach() for g in gs])
    return GaussianModel(cat("means"), cat("log_scales"), cat("quats"), cat("opacity_logits"), torch.cat(sh),
                         feats, active_sh_degree=max(g.active_sh_degree for g in gs))


def compose(base: EditableModel, part: EditableModel, transform: RigidTransform | None = None,
            time_offset: float = 0.0) -> EditableModel:
    """``base`` with ``part`` inserted, moved by ``transform`` and shown at its own time
    clamp(t + time_offset, 0, 1); each keeps its own deformation. The part's cluster ids are
    shifted past the base's so both stay selectable."""
    if part.num_gaussians == 0:
        raise EditError("compose: the part to insert has no gaussians (empty selection?)")
    tf = transform or RigidTransform()
    moved = transform_gaussians(part.gaussians, tf)
    plain = tf.is_identity and time_offset == 0.0
    part_def = part.deformation if plain else TransformedDeformation(part.deformation, tf, time_offset)
    if base.num_gaussians == 0:
        return EditableModel(moved, part_def, part.labels.copy(), part.keep.copy())
    g = _concat_gaussians([base.gaussians, moved])
    deform = ConcatDeformation([base.deformation, part_def], [base.num_gaussians, part.num_gaussians])
    shift = base.n_clusters
    labels = np.concatenate([base.labels, np.where(part.labels >= 0, part.labels + shift, -1)])
    return EditableModel(g, deform, labels, np.concatenate([base.keep, part.keep]))
