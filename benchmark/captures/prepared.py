"""A multi-view recording (Neu3D, Immersive or Technicolor raw format) after ``trase-bench
prepare``: ``prepared.json``, ``cameras.json``, ``images/<camera>/<frame>.png``, ``points.npy``
(in the folder or in its ``prepared/``). The raw videos and PNGs go through ``prepare`` first,
as for the benchmarks; the registry's held-out camera is the layout's test view
(``--holdout layout``), and every camera trains by default."""

from __future__ import annotations

from pathlib import Path

from benchmark.captures.common import CaptureLayout, capture_scene, normalize_scene
from benchmark.captures.options import CaptureOptions
from benchmark.datasets.errors import fail
from benchmark.datasets.jsonio import field, read_json


def _dir(scene_dir: Path) -> Path | None:
    for d in (scene_dir, scene_dir / "prepared"):
        if (d / "prepared.json").is_file():
            return d
    return None


def detect(scene_dir: Path) -> bool:
    return _dir(scene_dir) is not None


def load(scene_dir: Path, options: CaptureOptions):
    from benchmark.datasets.prepared import load_prepared
    from benchmark.datasets.registry import DATASETS

    pdir = _dir(scene_dir)
    if pdir is None:
        raise fail(scene_dir / "prepared.json", "missing (run trase-bench prepare on the raw recording first)")
    key = field(read_json(pdir / "prepared.json", "prepared.json"), "dataset", pdir / "prepared.json")
    if key not in DATASETS:
        raise fail(pdir / "prepared.json", f"prepared for unknown dataset {key!r}")
    scene = load_prepared(DATASETS[key], pdir, scene_dir.resolve().name)
    notices: list[str] = [f"frames prepared from a {DATASETS[key].display_name} recording"]
    out = capture_scene(scene_dir, scene.train + scene.test, options, {v.name for v in scene.test},
                        scene.points, scene.point_colors, notices,
                        {"image_scale": options.image_scale or 1,
                         "scale_on_the_fly": (options.image_scale or 1, "the prepared frames")})
    return normalize_scene(out, options, notices)


LAYOUT = CaptureLayout("prepared.json (trase-bench prepare)", detect, load)
