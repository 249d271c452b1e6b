"""How much of a monocular sequence's frames carry new content (``trase-bench perf frames``):
each training frame's novelty against its time-neighbours (trase.frame_novelty) on the built-in
monocular formats' scenes and on D-NeRF scenes as published (``--scene``). A reconstruction could
sample a frame less often only where its novelty is far below the sequence's median; the suite
reports the share of frames below a half and a quarter of it."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmark.perf.common import load_average, table

DATASETS = ["nerfds", "hypernerf"]  # the monocular formats (one view per time)
HEADER = ["scene", "frames", "median novelty", "below half", "below quarter", "least / median"]


def builtin_frames(dataset: str, size: str) -> list[np.ndarray]:
    """The training images of a built-in scene, in time order."""
    from benchmark.datasets import load_scene
    from benchmark.datasets.synthetic.cache import ensure_synthetic
    from imagefiles import read_rgb

    scene = load_scene(dataset, ensure_synthetic(dataset, size=size))
    return [read_rgb(v.image_path) for v in sorted(scene.train, key=lambda v: (v.time, v.name))]


def dnerf_frames(scene_dir: Path) -> list[np.ndarray]:
    """A D-NeRF scene's training images (RGBA over black), in time order."""
    from imagefiles import read_rgb

    doc = json.loads((Path(scene_dir) / "transforms_train.json").read_text())
    frames = sorted(doc["frames"], key=lambda f: float(f.get("time", 0.0)))
    paths = [Path(scene_dir) / (f["file_path"] + ("" if f["file_path"].endswith(".png") else ".png")) for f in frames]
    return [read_rgb(p, background=(0.0, 0.0, 0.0)) for p in paths]


def run(quick: bool = False, echo: Callable[[str], None] = print, scenes: list[str] | None = None) -> dict:
    from trase.frame_novelty import frame_novelty, novelty_summary

    size = "tiny" if quick else "small"
    sources = [(f"{ds} ({size})", lambda ds=ds: builtin_frames(ds, size)) for ds in DATASETS]
    sources += [(Path(s).name, lambda s=s: dnerf_frames(Path(s))) for s in scenes or []]
    rows, out = [], {}
    for name, frames in sources:
        summary = novelty_summary(frame_novelty(frames()))
        out[name] = summary
        rows.append([name, str(summary["frames"]), f"{summary['median']:.4f}", f"{summary['below_half']:.0%}",
                     f"{summary['below_quarter']:.0%}", f"{summary.get('min_to_median', 0.0):.2f}"])
    echo("novelty = a frame's mean absolute difference to the nearer of its time-neighbours (images in [0, 1], "
         "at most 64 px on the longer side)")
    echo(table(rows, HEADER))
    return {"description": __doc__.split("\n\n")[0], "quick": quick, "size": size, "scenes": out,
            "load_average_end": load_average()}


__all__ = ["DATASETS", "dnerf_frames", "run"]
