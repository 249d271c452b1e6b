"""Stage ``tracks``: ids consistent across the training views (masks.tracked), after ``geometry``.

Runs where ``masks.tracking`` is not ``none`` (a method that declares ``needs_tracks`` gets
``classical`` by default); otherwise it adds no stage and no key, so untracked runs are as
before. Its folder holds the masks stage's anything masks (hard links) beside the track ids and
``tracks.json``, and is the ``masks_dir`` the method's ``learn`` then receives. Sources:

- ``synthetic``: the synthetic scene's instance maps (the generator's ground truth), instance
  ids mapped to 1..K in ascending order; ``tracks.json`` source ``synthetic-truth``. A protocol
  of its own: ids from ground truth, never a tracker's;
- ``files``: per-frame id images a user brings (``masks.tracks_dir``; DEVA's output), ids mapped
  to 1..K in ascending order of the files' ids (``find_track_files``);
- ``classical``: the project's tracker over the anything masks
  (benchmark.pipeline.classical_tracker).

Keys: the tracking settings and the masks stage's key, plus the scene (synthetic), the files'
checksums (files), or the geometry stage's key and the tracker's constants (classical).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from benchmark.cache import StageRecord
from benchmark.config import ConfigError
from benchmark.pipeline.classical_tracker import CLASSICAL, track_classical
from benchmark.pipeline.context import SequenceRun, synthetic_truth

# where a DEVA output folder keeps its per-frame images: Annotations/ (demo_automatic.py and
# demo_with_text.py), object_mask/ (Gaussian Grouping's copy of it), else the folder itself
FILE_SUBDIRS = ("Annotations", "object_mask")
FILE_SUFFIXES = (".png",)


def run(ctx: SequenceRun) -> list[StageRecord]:
    settings = ctx.settings.masks
    if getattr(settings, "tracking", "none") == "none":
        return []
    masks_rec = ctx.records["masks"]
    cfg = {"tracking": settings.tracking}
    inputs = {"masks": masks_rec.key}
    if settings.tracking == "synthetic":
        inputs["scene"] = ctx.scene_key
    elif settings.tracking == "files":
        src = Path(settings.tracks_dir)
        cfg["tracks_dir"] = str(src)
        inputs["files"] = _files_key(ctx.scene.train, src)
    else:
        cfg["classical"] = CLASSICAL
        inputs["geometry"] = ctx.records["geometry"].key
    key = ctx.cache.key("tracks", cfg, inputs)

    def work(d: Path) -> dict:
        link_masks(ctx.scene.train, masks_rec.path, d)
        if settings.tracking == "synthetic":
            return write_synthetic(ctx.scene, d)
        if settings.tracking == "files":
            return write_files(ctx.scene.train, Path(settings.tracks_dir), d)
        gaussians, deformation = ctx.geometry
        return track_classical(ctx.scene.train, gaussians, deformation, d, truth=ctx.scene.truth,
                               progress=ctx.progress)

    return [ctx.cache.run("tracks", key, work, cfg)]


def link_masks(views, src: Path, out: Path) -> None:
    """The anything masks of every view beside the ids (hard links; copies where the file system
    has none), so one folder is the method's masks_dir."""
    import masks as masklib

    for v in views:
        a, b = masklib.mask_path(src, v.name), masklib.mask_path(out, v.name)
        b.unlink(missing_ok=True)
        try:
            os.link(a, b)
        except OSError:
            shutil.copy2(a, b)


def _check_size(path, ids: np.ndarray, view) -> None:
    from masks.tracked import TrackFileError

    want = (view.camera.height, view.camera.width)
    if ids.shape != want:
        raise TrackFileError(path, f"ids are {ids.shape[1]}x{ids.shape[0]} but training view {view.name} is "
                                   f"{want[1]}x{want[0]} (WxH)")


def _save_all(views, maps: list[np.ndarray], out: Path) -> None:
    from masks.tracked import ids_path, save_ids

    for v, ids in zip(views, maps):
        save_ids(ids_path(out, v.name), ids)


# -- synthetic: the generator's instance maps ---------------------------------------------------
def write_synthetic(scene, out: Path) -> dict:
    """Track ids from the synthetic scene's instance maps (ground truth)."""
    from masks.generate import read_instance_map
    from masks.tracked import remap_ids, save_tracks_info

    truth = synthetic_truth(scene)
    maps = []
    for v in scene.train:
        path = truth.instance_maps.get(v.name)
        if path is None:
            raise ConfigError(f"{truth.manifest_path}: no instance map for training view {v.name}")
        ids = read_instance_map(path)
        _check_size(path, ids, v)
        maps.append(ids)
    tracked, mapping = remap_ids(maps)
    _save_all(scene.train, tracked, out)
    names = {o.id: o.name for o in truth.objects}
    info = {"source": "synthetic-truth", "n_tracks": len(mapping), "views": len(scene.train),
            "instance_of_track": {str(k): i for i, k in mapping.items()},
            "name_of_track": {str(k): names.get(i, "") for i, k in mapping.items()}}
    save_tracks_info(out, info)
    return {"source": "synthetic-truth", "n_tracks": len(mapping)}


# -- files: a tracker's output a user brings ----------------------------------------------------
def files_root(src: Path) -> Path:
    """The folder of per-frame images in ``src``: its ``Annotations/`` or ``object_mask/`` where
    present (the first), else ``src`` itself."""
    if not src.is_dir():
        raise ConfigError(f"{src}: masks.tracks_dir is not a folder")
    return next((src / s for s in FILE_SUBDIRS if (src / s).is_dir()), src)


def _file_candidates(root: Path, view) -> list[Path]:
    """A view's id image in ``root``: named after the view (``/`` -> ``__``) or after its image
    (the image's path without its suffix, keeping up to its two parent folders, longest first;
    DEVA names each output after its input image), with a suffix of FILE_SUFFIXES."""
    parts = Path(view.image_path).with_suffix("").parts
    names = [view.name.replace("/", "__"), *("/".join(parts[-k:]) for k in (3, 2, 1) if len(parts) >= k)]
    names = list(dict.fromkeys(names))
    return [root / f"{n}{s}" for n in names for s in FILE_SUFFIXES]


def find_track_files(views, src: Path) -> tuple[Path, list[Path]]:
    """(the folder read, one id image per training view, in view order); a view without one is
    a one-line error naming where it was looked for."""
    root = files_root(src)
    found = []
    for v in views:
        cands = _file_candidates(root, v)
        hit = next((c for c in cands if c.is_file()), None)
        if hit is None:
            others = ", ".join(str(c.relative_to(root)) for c in cands[1:])
            raise ConfigError(f"{cands[0]}: no track ids for training view {v.name} in masks.tracks_dir (nor {others})")
        found.append(hit)
    return root, found


def _files_key(views, src: Path) -> str:
    from benchmark.io import sha256_files

    return sha256_files(find_track_files(views, src)[1])[:16]


def write_files(views, src: Path, out: Path) -> dict:
    """Track ids from per-frame id images (``masks.tracked.read_id_image``), remapped to 1..K."""
    from masks.tracked import read_id_image, remap_ids, save_tracks_info

    root, files = find_track_files(views, src)
    maps = []
    for v, f in zip(views, files):
        ids = read_id_image(f)
        _check_size(f, ids, v)
        maps.append(ids)
    tracked, mapping = remap_ids(maps)
    _save_all(views, tracked, out)
    info = {"source": "files", "n_tracks": len(mapping), "views": len(views), "tracks_dir": str(src),
            "read_from": str(root), "files": {v.name: str(f.relative_to(root)) for v, f in zip(views, files)},
            "id_in_files_of_track": {str(k): o for o, k in mapping.items()}}
    save_tracks_info(out, info)
    return {"source": "files", "n_tracks": len(mapping), "read_from": str(root)}


__all__ = ["find_track_files", "link_masks", "run", "write_files", "write_synthetic"]
