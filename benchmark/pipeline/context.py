"""What every stage of one sequence reads: the scene, the resolved settings, the method, the
stage cache and the records of the stages before it."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
from pathlib import Path

import numpy as np

from benchmark.cache import StageCache, StageRecord
from benchmark.config import ConfigError
from benchmark.pipeline.settings import RunSettings


@dataclasses.dataclass
class SequenceRun:
    cache: StageCache
    scene: object  # benchmark.datasets.Scene
    settings: RunSettings  # resolved once per sequence (benchmark.pipeline.settings)
    method: object  # benchmark.methods.Method
    progress: bool
    scene_key: str  # scene_fingerprint(scene)
    gt_key: str  # checksum of the ground-truth masks
    records: dict[str, StageRecord] = dataclasses.field(default_factory=dict)

    @functools.cached_property
    def geometry(self) -> tuple:
        """(gaussians, deformation) of the geometry stage, loaded at most once per sequence and
        only by a stage that has to run."""
        return load_geometry(self.records["geometry"].path)


def load_geometry(stage_dir: Path) -> tuple:
    """(gaussians, deformation) from a geometry stage directory."""
    from trase.checkpoint import load_model, load_tabulated_geometry

    if (stage_dir / "geometry.npz").exists():
        g, deform, _ = load_tabulated_geometry(stage_dir / "geometry.npz")
        return g, deform
    return load_model(stage_dir / "model")


def render_near(source: str, train_near: float) -> float:
    """The near plane every stage renders a geometry with: the one a reconstruction was trained
    with (``geometry.train.near_plane``: 0.2 in the paper preset, as the public rasterizer; 0.01
    in the cpu presets), else the cameras' default (ground truth, an imported model: as before).
    Why: gaussians nearer than the training plane were never drawn, so never fitted to an image."""
    from trase.camera import NEAR_PLANE

    return float(train_near) if source == "reconstruct" else NEAR_PLANE


def recorded_render_near(config: dict) -> float:
    """``render_near`` of a run's or fit's recorded config (a near plane at the cameras' default
    is left out of the record: benchmark.pipeline.settings.AS_BEFORE)."""
    from trase.camera import NEAR_PLANE

    geometry = config.get("geometry", {})
    return render_near(geometry.get("source", "reconstruct"), geometry.get("train", {}).get("near_plane", NEAR_PLANE))


def synthetic_truth(scene):
    """The scene's truth (benchmark.datasets.truth); a clear error on real data."""
    if scene.truth is None:
        raise ConfigError(f"{scene.root}: not a synthetic scene (no synthetic/manifest.json)")
    return scene.truth


def scene_fingerprint(scene) -> str:
    """Key of the input data: cameras, times and each image's name, size and mtime."""
    h = hashlib.sha256()
    for v in scene.train + scene.test:
        st = os.stat(v.image_path)
        h.update(json.dumps([v.name, v.camera.to_dict(), str(v.image_path), st.st_size,
                             st.st_mtime_ns], sort_keys=True).encode())
    h.update(np.ascontiguousarray(scene.points, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


def jsonable(obj):
    """``obj`` with numpy values turned into plain JSON values."""
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
