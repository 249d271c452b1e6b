"""Stages ``features`` and ``fit``: the method's ``learn`` (per-gaussian features), then its
``group`` (clusters and the filter), cached apart so a clustering or filtering change reuses
the trained features."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from benchmark.cache import StageRecord
from benchmark.pipeline.context import SequenceRun, jsonable
from benchmark.pipeline.settings import key_config
from benchmark.plugins import feature_packages


def _packages(method, settings) -> dict:
    """The plugins that make the features, keyed with their versions (nothing for built-ins,
    so their keys stay as they were)."""
    found = feature_packages(method, settings)
    return {"packages": found} if found else {}


def _features(ctx: SequenceRun) -> StageRecord:
    """Learned per-gaussian features: keyed only on the settings that change them."""
    method, settings = ctx.method, ctx.settings.method
    masks_rec, geo_rec = ctx.records["masks"], ctx.records["geometry"]
    fields = method.FEATURE_FIELDS
    learned = {k: key_config(getattr(settings, k)) for k in fields} if fields is not None else {"settings": key_config(settings)}
    fcfg = {"method": method.name, **learned, **_packages(method, ctx.settings)}
    inputs = {"masks": masks_rec.key, "geometry": geo_rec.key}
    tracks_rec = ctx.records.get("tracks")  # tracked masks: their folder holds the masks and the ids
    if tracks_rec is not None:
        masks_rec, inputs = tracks_rec, {**inputs, "tracks": tracks_rec.key}
    key = ctx.cache.key("features", fcfg, inputs)

    def work(d: Path) -> dict:
        gaussians, deformation = ctx.geometry
        feats, info = method.learn(ctx.scene, gaussians, deformation, masks_rec.path, settings, d / "work",
                                   progress=ctx.progress)
        np.save(d / "features.npy", feats)
        shutil.rmtree(d / "work", ignore_errors=True)  # pixel-weight cache, not a result
        return jsonable(info)

    return ctx.cache.run("features", key, work, fcfg)


def run(ctx: SequenceRun) -> list[StageRecord]:
    method, settings = ctx.method, ctx.settings.method
    geo_rec = ctx.records["geometry"]
    fit_cfg = {"method": method.name, **key_config(settings)}
    feat_rec = _features(ctx)
    key = ctx.cache.key("fit", fit_cfg, {"features": feat_rec.key, "geometry": geo_rec.key})

    def work(d: Path) -> dict:
        gaussians, deformation = ctx.geometry
        feats = np.load(feat_rec.path / "features.npy")
        extra = method.group_inputs(ctx.scene, gaussians, deformation, settings)  # e.g. training weights
        fitted = method.group(feats, settings, gaussians, deformation, {**feat_rec.info, **extra})
        fitted.save(d)
        return {"timings": fitted.timings, "stats": jsonable(fitted.stats)}

    return [feat_rec, ctx.cache.run("fit", key, work, fit_cfg)]
