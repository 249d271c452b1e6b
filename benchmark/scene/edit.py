"""``trase-bench edit``: one edit of a scene folder written as a new, reopenable folder.

    <out>/model/         the edited geometry (trase.edit.save_edited: public layout, or a
                         baked motion table for compositions)
    <out>/segmentation/  clusters.npy, keep.npy (learned features are columns of model/'s PLY)
    <out>/views.json     the source folder's cameras (render, view and further edits use them)
    <out>/preview.png    before | after at the middle view
    <out>/edit.json      what was done, to what, from where (written last: its presence
                         marks a finished folder)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmark.errors import UserError
from benchmark.scene.folders import CLICK_SETTINGS, EDIT_FILE, VIEWS_FILE, SceneFolder, views_doc


def write_edit(source: SceneFolder, edited, out: Path, operation: str, params: dict) -> Path:
    """Write ``edited`` (an EditableModel) as an edit folder of ``source``; returns edit.json."""
    from benchmark.io import atomic_write_bytes, atomic_write_json
    from imagefiles import png_bytes
    from trase.edit import save_edited
    from trase.visualize import Painter

    out = Path(out)
    if out.resolve() == source.path.resolve():
        raise UserError(f"--out {out}: must differ from the folder being edited")
    if (out / EDIT_FILE).is_file():
        (out / EDIT_FILE).unlink()  # the folder is rewritten below; no stale record meanwhile
    save_edited(edited, out, times=source.times())  # learned features travel in the PLY's feature columns
    atomic_write_json(out / VIEWS_FILE, views_doc(source.views))
    name, cam = source.views[len(source.views) // 2]
    before, after = Painter(source.model).render(cam, "rgb"), Painter(edited).render(cam, "rgb")
    atomic_write_bytes(out / "preview.png", png_bytes(np.concatenate([before, after], axis=1)))
    record = {
        "kind": "edit", "operation": operation, "params": params,
        "source": str(source.path.resolve()), "source_kind": source.kind, "dataset": source.dataset,
        **{name: getattr(source, name) for name in CLICK_SETTINGS},  # the source's click settings
        "n_gaussians": {"before": source.model.num_gaussians, "after": edited.num_gaussians},
        "n_clusters": edited.n_clusters, "preview": "preview.png", "preview_view": name,
        "motion": "network" if (out / "model/deform/iteration_1/deform.pth").is_file() else
                  "table" if (out / "model/deform").exists() else "static",
    }
    atomic_write_json(out / EDIT_FILE, record)
    return out / EDIT_FILE


def parse_vector(text: str | None, what: str, n: int = 3) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != n or not all(np.isfinite(vals)):
        raise UserError(f"{what} {text!r}: expected {n} numbers separated by commas")
    return vals


__all__ = ["parse_vector", "write_edit"]
