"""Stage ``masks``: per-image "anything" masks of the training views (the method's input)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmark.cache import StageRecord
from benchmark.config import ConfigError
from benchmark.pipeline.context import SequenceRun, synthetic_truth


def make_mask_generator(mcfg: dict):
    """The generator of the ``masks`` config section."""
    from masks.generators import make_generator

    g = mcfg["generator"]
    if g == "sam":
        if not mcfg.get("checkpoint"):
            raise ConfigError("masks.generator=sam needs --set masks.checkpoint=PATH (a SAM .pth file)")
        return make_generator("sam", checkpoint=mcfg["checkpoint"])
    if g == "synthetic":
        return make_generator("synthetic", seed=mcfg["seed"])
    return make_generator(g)


def run(ctx: SequenceRun) -> list[StageRecord]:
    import masks as masklib

    mcfg = ctx.cfg["masks"]
    # an RGBA image is composited over the reconstruction's background (imagefiles' rule), so
    # masks are cut from the picture the geometry trains on
    white = bool(ctx.cfg["geometry"].get("train", {}).get("white_background", False))
    key = ctx.cache.key("masks", mcfg, {"scene": ctx.scene_key, "background": "white" if white else "black"})

    def work(d: Path) -> dict:
        instance_maps = synthetic_truth(ctx.scene).instance_maps if mcfg["generator"] == "synthetic" else None
        paths = masklib.generate_scene_masks(ctx.scene.train, make_mask_generator(mcfg), d,
                                             progress=ctx.progress, instance_maps=instance_maps,
                                             background=(1.0, 1.0, 1.0) if white else None)
        sizes = [p.stat().st_size for p in paths]
        return {"n_views": len(paths), "bytes_per_view": int(np.mean(sizes)) if sizes else 0}

    return [ctx.cache.run("masks", key, work, mcfg)]
