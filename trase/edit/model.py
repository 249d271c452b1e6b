"""The thing edits act on: gaussians, their deformation, and what segmentation said of them."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from trase.gaussians import GaussianModel


class EditError(ValueError):
    """An edit that cannot be made as asked (wrong selection size, bad colour, ...)."""

    user_facing = True


@dataclasses.dataclass
class EditableModel:
    """gaussians [N], deformation (a ``trase.deformation.Deformation`` or None for a static
    scene), labels [N] int64 cluster ids (-1: none), keep [N] bool (passes the filter)."""

    gaussians: GaussianModel
    deformation: object | None
    labels: np.ndarray
    keep: np.ndarray

    def __post_init__(self) -> None:
        n = self.gaussians.num_gaussians
        self.labels = np.asarray(self.labels, dtype=np.int64).reshape(-1)
        self.keep = np.asarray(self.keep, dtype=bool).reshape(-1)
        if self.labels.shape[0] != n or self.keep.shape[0] != n:
            raise EditError(f"{n} gaussians but {self.labels.shape[0]} labels and {self.keep.shape[0]} keep flags")

    @classmethod
    def unlabelled(cls, gaussians: GaussianModel, deformation=None) -> EditableModel:
        """A model with no segmentation: every gaussian in cluster 0 and kept."""
        n = gaussians.num_gaussians
        return cls(gaussians, deformation, np.zeros(n, np.int64), np.ones(n, bool))

    @property
    def num_gaussians(self) -> int:
        return self.gaussians.num_gaussians

    @property
    def n_clusters(self) -> int:
        return int(self.labels.max()) + 1 if self.labels.size and self.labels.max() >= 0 else 0

    def check_selection(self, selection: np.ndarray) -> np.ndarray:
        sel = np.asarray(selection)
        if sel.dtype != bool or sel.shape != (self.num_gaussians,):
            raise EditError(f"a selection must be a bool array of shape ({self.num_gaussians},), "
                            f"got {sel.dtype} {sel.shape}")
        return sel

    def subset(self, mask: np.ndarray) -> EditableModel:
        """The gaussians where ``mask`` [N] bool is True, same deformation (exact: the network
        maps each gaussian's own canonical position; a tabulated one keeps its rows)."""
        mask = self.check_selection(mask)
        g = self.gaussians.copy()
        g.prune(torch.from_numpy(mask))
        return EditableModel(g, subset_deformation(self.deformation, mask), self.labels[mask], self.keep[mask])


def subset_deformation(deformation, mask: np.ndarray):
    """The deformation of the gaussians in ``mask`` (``trase.deformation.deformation_rows``)."""
    from trase.deformation import deformation_rows

    return deformation_rows(deformation, np.asarray(mask, bool))
