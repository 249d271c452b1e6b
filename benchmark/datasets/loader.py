"""``load_scene``: one entry point that reads any of the five benchmarks from disk.

Which reader runs is decided by the registry's format and by what is in the directory:

* nerfies (NeRF-DS, HyperNeRF): ``dataset.json`` ... read directly, no preparation needed.
* multi-view (Neu3D, Immersive, Technicolor):
  1. ``prepared.json`` in the directory or in ``<dir>/prepared/``: what ``trase-bench prepare``
     wrote (frames at training resolution, undistorted, principal point centred);
  2. ``transforms_train.json`` + ``transforms_test.json``: the layout the paper's public code
     writes (its ``*2blender.py`` scripts), read as is;
  3. raw publisher data (videos / full-size PNGs): not read directly, because extracting and
     undistorting thousands of frames is a long job that should not hide inside a loader; the
     error says which ``trase-bench prepare`` command to run.
"""

from __future__ import annotations

from pathlib import Path

from benchmark.datasets.errors import fail
from benchmark.datasets.layout import align_gt, find_gt_dir
from benchmark.datasets.registry import get_dataset
from benchmark.datasets.scene import Scene

PREPARED_MANIFEST = "prepared.json"


def prepared_dir(scene_dir: Path) -> Path | None:
    """The directory holding ``prepared.json`` for this scene, if any."""
    for d in (scene_dir, scene_dir / "prepared"):
        if (d / PREPARED_MANIFEST).is_file():
            return d
    return None


def load_scene(
    dataset: str,
    scene_dir: Path | str,
    sequence: str | None = None,
    *,
    data_root: Path | str | None = None,
    gt_dir: Path | str | None = None,
) -> Scene:
    """Read one sequence of ``dataset`` from ``scene_dir`` into a ``Scene``.

    ``sequence`` defaults to the directory name (a publisher alias is accepted). Ground truth:
    ``gt_dir`` if given, else found by ``find_gt_dir``; when none exists ``scene.gt_masks`` is
    empty and ``scene.extras["gt_dir"]`` is None (training works, scoring will say so).
    """
    spec = get_dataset(dataset)
    scene_dir = Path(scene_dir)
    if not scene_dir.is_dir():
        raise fail(scene_dir, "scene directory does not exist")
    seq_name = sequence if sequence is not None else _sequence_from_dir(scene_dir)
    seq = spec.resolve_sequence(seq_name) if sequence is not None else _lenient(spec, seq_name)

    if spec.format == "nerfies":
        from benchmark.datasets.nerfies import load_nerfies

        scene = load_nerfies(spec, scene_dir, seq)
    else:
        pdir = prepared_dir(scene_dir)
        if pdir is not None:
            from benchmark.datasets.prepared import load_prepared

            scene = load_prepared(spec, pdir, seq)
        elif (scene_dir / "transforms_train.json").is_file():
            from benchmark.datasets.transforms import load_transforms

            scene = load_transforms(spec, scene_dir, seq)
        else:
            raise fail(
                scene_dir,
                f"no prepared frames ({PREPARED_MANIFEST}) or transforms_train.json; run "
                f"`trase-bench prepare {spec.key} {scene_dir} {scene_dir / 'prepared'}` first",
            )
        scene.root = scene_dir

    # ground truth, aligned with the test views
    gdir = Path(gt_dir) if gt_dir is not None else find_gt_dir(spec.key, seq, data_root, scene_dir)
    if gdir is not None:
        if not gdir.is_dir():
            raise fail(gdir, "ground-truth directory does not exist")
        scene.gt_masks = align_gt(gdir, len(scene.test))
        _check_gt_sizes(scene)
    scene.extras["gt_dir"] = str(gdir) if gdir is not None else None

    from benchmark.datasets.truth import find_truth

    scene.truth = find_truth(scene_dir)
    if scene.truth is not None:
        scene.variant = "synthetic"
    return scene


def _sequence_from_dir(scene_dir: Path) -> str:
    return scene_dir.parent.name if scene_dir.name == "prepared" else scene_dir.name


def _lenient(spec, name: str) -> str:
    """A directory name that is no known sequence is still loadable (e.g. synthetic scenes);
    the canonical name is used when it resolves."""
    from benchmark.datasets.errors import DatasetError

    try:
        return spec.resolve_sequence(name)
    except DatasetError:
        return name


def _check_gt_sizes(scene: Scene) -> None:
    from benchmark.datasets.images import image_size

    for view, path in zip(scene.test, scene.gt_masks):
        w, h = image_size(path)
        if (w, h) != (view.camera.width, view.camera.height):
            raise fail(
                path,
                f"ground-truth mask is {w}x{h} but test view {view.name} is "
                f"{view.camera.width}x{view.camera.height}",
            )
