"""Stage ``masks``: per-image "anything" masks of the training views (the method's input)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from benchmark.cache import StageRecord
from benchmark.config import ConfigError
from benchmark.pipeline.context import SequenceRun, synthetic_truth
from benchmark.pipeline.settings import TRACKING_FIELDS, MaskSettings
from benchmark.plugins import mask_packages


def make_mask_generator(settings: MaskSettings):
    """The generator of the ``masks`` settings."""
    from masks.generators import make_generator

    g = settings.generator
    if g == "sam":
        if settings.checkpoint:
            return make_generator("sam", checkpoint=settings.checkpoint, **_model_type(settings))
        if settings.model:
            from masks.checkpoints import sam_checkpoint

            return make_generator("sam", checkpoint=sam_checkpoint(settings.model), model_type=settings.model)
        raise ConfigError("masks.generator=sam needs --set masks.model=vit_b|vit_l|vit_h (the official checkpoint, "
                          "fetched once) or --set masks.checkpoint=PATH (a SAM .pth file)")
    if g == "synthetic":
        return make_generator("synthetic", seed=settings.seed)
    return make_generator(g)


def _model_type(settings: MaskSettings) -> dict:
    """A local checkpoint's architecture: masks.model where named (the generator's default vit_h else)."""
    return {"model_type": settings.model} if settings.model else {}


def _candidates(src: Path, view) -> list[Path]:
    """Where a view's masks may lie in masks.dir: named after the view or after its image (the
    image's path without its suffix, keeping up to its two parent folders, longest first, so
    ``cam01/00001`` is found for a multi-camera capture's ``images/cam01/00001.png``), in this
    project's format (``.masks``, what ``trase-bench masks`` writes) or the paper's
    (``<image stem>.pt``, its SAM script's output)."""
    import masks as masklib

    parts = Path(view.image_path).with_suffix("").parts
    names = [view.name, *("/".join(parts[-k:]) for k in (3, 2, 1) if len(parts) >= k)]
    names = list(dict.fromkeys(names))  # once each, in order
    return [*(masklib.mask_path(src, n) for n in names), src / f"{parts[-1]}.pt"]


def masks_from_files(views, src: Path, out: Path) -> list[Path]:
    """Masks made elsewhere (SAM on another machine, the paper's code) for every training
    view (``_candidates``), each read and checked, then stored."""
    import masks as masklib

    out_paths = []
    for v in views:
        candidates = _candidates(src, v)
        found = next((c for c in candidates if c.is_file()), None)
        if found is None:
            others = ", ".join(str(c.relative_to(src)) for c in candidates[1:])
            raise ConfigError(f"{candidates[0]}: no masks for training view {v.name} in masks.dir (nor {others})")
        ms = masklib.load(found)
        ms.info.update({"view": v.name, "source": str(found)})
        out_paths.append(masklib.mask_path(out, v.name))
        masklib.save(out_paths[-1], ms)
    return out_paths


def _files_key(views, src: Path) -> str:
    from benchmark.io import sha256_files

    found = [next((c for c in _candidates(src, v) if c.is_file()), None) for v in views]
    return sha256_files([p for p in found if p is not None])[:16]


def run(ctx: SequenceRun) -> list[StageRecord]:
    import masks as masklib

    settings = ctx.settings.masks
    # what the key hashes: the anything masks do not depend on tracking (the tracks stage's own)
    mcfg = {k: v for k, v in dataclasses.asdict(settings).items() if k not in TRACKING_FIELDS}
    if mcfg.get("model") is None:
        mcfg.pop("model", None)  # keys of runs that name no SAM model stay as they were
    if settings.generator == "files":
        if not getattr(settings, "dir", None):
            raise ConfigError("masks.generator=files (trase-bench fit) needs --set masks.dir=PATH (a folder of mask files)")
        src = Path(settings.dir)
        if not src.is_dir():
            raise ConfigError(f"{src}: masks.dir is not a folder")
        key = ctx.cache.key("masks", mcfg, {"scene": ctx.scene_key, "files": _files_key(ctx.scene.train, src)})

        def copy(d: Path) -> dict:
            paths = masks_from_files(ctx.scene.train, src, d)
            return {"n_views": len(paths), "source": str(src)}

        return [ctx.cache.run("masks", key, copy, mcfg)]
    # an RGBA image is composited over the reconstruction's background (imagefiles' rule), so
    # masks are cut from the picture the geometry trains on
    white = bool(ctx.settings.geometry.train.white_background)
    plugin = mask_packages(ctx.settings)  # a generator from another package: keyed by its version too
    key = ctx.cache.key("masks", mcfg, {"scene": ctx.scene_key, "background": "white" if white else "black",
                                        **({"packages": plugin} if plugin else {})})

    def work(d: Path) -> dict:
        instance_maps = synthetic_truth(ctx.scene).instance_maps if settings.generator == "synthetic" else None
        paths = masklib.generate_scene_masks(ctx.scene.train, make_mask_generator(settings), d,
                                             progress=ctx.progress, instance_maps=instance_maps,
                                             background=(1.0, 1.0, 1.0) if white else None)
        sizes = [p.stat().st_size for p in paths]
        return {"n_views": len(paths), "bytes_per_view": int(np.mean(sizes)) if sizes else 0}

    return [ctx.cache.run("masks", key, work, mcfg)]
