"""Editing a fitted dynamic scene: select gaussians, remove, extract, recolour, compose, save.

An ``EditableModel`` is gaussians + their deformation + per-gaussian cluster labels and the
filter's keep mask. Every edit returns a new model and leaves its input untouched, so an
editor can undo by keeping the previous one. Edits are exact where they can be: removing or
extracting gaussians keeps the deformation network as is (it is evaluated per gaussian), and
a rigid transform of a composed part is folded into its offsets (``rigid``), so a composition
renders each part with its own motion.
"""

from trase.edit.model import EditableModel, EditError
from trase.edit.ops import compose, extract, recolor, remove
from trase.edit.rigid import RigidTransform
from trase.edit.save import export_object_ply, load_edited, save_edited
from trase.edit.select import by_click, by_clusters, by_mask

__all__ = [
    "EditError", "EditableModel", "RigidTransform", "by_click", "by_clusters", "by_mask", "compose",
    "export_object_ply", "extract", "load_edited", "recolor", "remove", "save_edited",
]
