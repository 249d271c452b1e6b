"""Captures of one's own: scenes that are not benchmark sequences, read into a ``Scene`` for
``trase-bench fit`` (no ground truth, never in a leaderboard).

Layouts, each a module with ``detect(dir) -> bool`` and ``load(dir, options) -> Scene``:

* ``nerfies``: what the nerfies/HyperNeRF capture notebook writes (``dataset.json``,
  ``metadata.json``, ``scene.json``, ``camera/``, ``rgb/<s>x/``, ``points.npy`` or COLMAP's
  ``colmap/sparse/0``);
* ``colmap``: a COLMAP folder (``images/`` + ``sparse/0``), static or with time from the
  frame order or a ``times.json``;
* ``transforms``: ``transforms_train.json`` (+ ``transforms_test.json``), the layout of the
  paper's public code and of D-NeRF;
* ``prepared``: a multi-view recording in a benchmark's raw format after ``trase-bench
  prepare`` (Neu3D, Immersive, Technicolor).

Usage::

    scene = load_capture("my_capture", CaptureOptions(format="auto", holdout="every:8"))
"""

from __future__ import annotations

from pathlib import Path

from benchmark.captures.options import CaptureOptions
from benchmark.datasets.errors import DatasetError, fail
from lazyspecs import Registry

FORMATS = Registry("capture format", DatasetError)
FORMATS.add("nerfies", "benchmark.captures.nerfies:LAYOUT", "nerfies/HyperNeRF capture notebook output")
FORMATS.add("colmap", "benchmark.captures.colmap:LAYOUT", "COLMAP folder: images/ + sparse/0")
FORMATS.add("transforms", "benchmark.captures.transforms:LAYOUT", "transforms_train.json (+ _test.json)")
FORMATS.add("prepared", "benchmark.captures.prepared:LAYOUT", "a multi-view recording after trase-bench prepare")


def detect_format(scene_dir: Path | str) -> str:
    """The one layout ``scene_dir`` is in, or an error listing what each layout looks for."""
    scene_dir = Path(scene_dir)
    if not scene_dir.is_dir():
        raise fail(scene_dir, "capture directory does not exist")
    found = [name for name in FORMATS.names() if FORMATS.load(name).detect(scene_dir)]
    if len(found) == 1:
        return found[0]
    if not found:
        wanted = "; ".join(f"{n}: {FORMATS.load(n).signature}" for n in FORMATS.names())
        raise fail(scene_dir, f"no known capture layout ({wanted})")
    raise fail(scene_dir, f"matches several capture layouts ({', '.join(found)}); choose one with --format")


def load_capture(scene_dir: Path | str, options: CaptureOptions | None = None):
    """Read a capture into a ``Scene`` (dataset "capture"); ``scene.extras["notices"]`` lists
    what the reader decided (ignored images, dropped lens distortion, time rule)."""
    options = options or CaptureOptions()
    scene_dir = Path(scene_dir)
    fmt = detect_format(scene_dir) if options.format == "auto" else options.format
    if fmt not in FORMATS:
        raise DatasetError(f"--format {fmt}: choose auto, {', '.join(FORMATS.names())}")
    if not scene_dir.is_dir():
        raise fail(scene_dir, "capture directory does not exist")
    scene = FORMATS.load(fmt).load(scene_dir, options)
    scene.extras["format"] = fmt
    return _scaled_scene(scene, options)


def _scaled_scene(scene, options: CaptureOptions):
    """The scene with its images scaled the rest of the way: what the layout's copies lack of
    ``image_scale``, then down to ``max_side``; said in a notice."""
    from benchmark.captures import scaling

    factor, source = scene.extras.pop("scale_on_the_fly", (1.0, ""))
    views = scene.train + scene.test
    cap = scaling.max_side_factor(views, options.max_side) if options.max_side else 1.0
    total = float(factor) * cap
    if total <= 1.0:
        return scene
    w0, h0 = views[0].camera.width, views[0].camera.height
    scene.train = scaling.rescale(scene.train, total)
    scene.test = scaling.rescale(scene.test, total)
    scene.validation = scaling.rescale(scene.validation, total)
    w1, h1 = scene.train[0].camera.width, scene.train[0].camera.height
    why = []
    if factor > 1:
        why.append(f"no copy at 1/{options.image_scale}: scaled 1/{factor:g} from {source}")
    if cap > 1:
        why.append(f"capture.max_side={options.max_side}")
    scene.extras["notices"].append(f"images scaled on the fly ({'; '.join(why)}): {w0}x{h0} -> {w1}x{h1}, "
                                   f"area filter, alpha kept, cached in {scaling.cache_root()}")
    scene.extras["scaled_on_the_fly"] = {"factor": total, "from": [w0, h0], "to": [w1, h1]}
    return scene


__all__ = ["FORMATS", "CaptureOptions", "detect_format", "load_capture"]
