"""What a loader returns: one sequence of a benchmark, ready to train and evaluate on.

Views carry *undistorted pinhole* cameras at the resolution training and the ground truth
use (the loader resamples images when the native lens has distortion, see ``prepare``);
``native_camera`` keeps the publisher's full lens model at native resolution.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from trase.camera import Camera

if TYPE_CHECKING:
    from benchmark.datasets.truth import SceneTruth

Variant = Literal["real", "synthetic"]


@dataclasses.dataclass(frozen=True)
class View:
    name: str  # unique within the scene, e.g. "cam03/00012" or the nerfies item id
    camera: Camera  # pinhole, at training resolution; camera.time in [0, 1]
    image_path: Path  # RGB image at exactly camera.width x camera.height
    frame: int  # index of the time step (frame number within the benchmark's range)
    native_camera: Camera | None = None  # full lens model at native resolution, if known

    @property
    def time(self) -> float:
        return self.camera.time


@dataclasses.dataclass
class Scene:
    dataset: str  # registry key: nerfds, hypernerf, neu3d, immersive, technicolor
    sequence: str  # e.g. "americano"
    root: Path  # directory the scene was read from
    train: list[View]
    test: list[View]
    points: np.ndarray  # [N, 3] float64 initial point cloud, world coordinates
    point_colors: np.ndarray | None = None  # [N, 3] float in [0, 1], if the format has them
    gt_masks: list[Path] = dataclasses.field(default_factory=list)  # aligned with test
    variant: Variant = "real"
    truth: SceneTruth | None = None  # synthetic scenes: objects, instance maps, geometry (datasets.truth)
    extras: dict = dataclasses.field(default_factory=dict)  # format-specific facts (scene.json ...)
    # views held out of training for choosing settings (D-NeRF's transforms_val.json): never
    # trained on and never a test view
    validation: list[View] = dataclasses.field(default_factory=list)

    def __post_init__(self) -> None:
        if self.gt_masks and len(self.gt_masks) != len(self.test):
            raise ValueError(
                f"{self.root}: {len(self.gt_masks)} ground-truth masks for {len(self.test)} test views"
            )

    def with_near(self, near: float) -> Scene:
        """The scene whose every camera culls at ``near``: renders of a geometry use the near
        plane it was trained with (``benchmark.pipeline.context.render_near``)."""
        def seen(views: list[View]) -> list[View]:
            return [dataclasses.replace(v, camera=v.camera.with_near(near)) for v in views]

        return dataclasses.replace(self, train=seen(self.train), test=seen(self.test), validation=seen(self.validation))

    @property
    def times(self) -> np.ndarray:
        """[T] sorted distinct normalised times over train and test views."""
        return np.unique([v.time for v in self.train + self.test])
