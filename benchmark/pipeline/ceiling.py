"""Stage ``ceiling``: the geometry's label ceiling (benchmark.protocol.ceiling) on synthetic scenes,
cached under the geometry, the ground truth and the rendering rule: every method and
ablation variant run on one geometry reuses it."""

from __future__ import annotations

from pathlib import Path

from benchmark.cache import StageRecord
from benchmark.pipeline.context import SequenceRun
from benchmark.scoring import read_mask

NOTE = ("geometry's ceiling: every gaussian labelled by the object it shows most in the training views' "
        "instance maps (synthetic scenes only); an estimate, not a strict bound; not the method's score")


def run(ctx: SequenceRun) -> list[StageRecord]:
    """[] on real data."""
    if ctx.scene.truth is None:
        return []
    method = ctx.settings.method  # the settings the fit was made with
    ccfg = {"rule": str(getattr(method, "render_rule", "alone")), "threshold": float(getattr(method, "alpha_threshold", 0.5))}
    key = ctx.cache.key("ceiling", ccfg, {"geometry": ctx.records["geometry"].key, "gt": ctx.gt_key})

    def work(d: Path) -> dict:
        from benchmark.protocol.ceiling import label_ceiling

        gaussians, deformation = ctx.geometry
        gts = [read_mask(p) for p in ctx.scene.gt_masks]
        score, info = label_ceiling(gaussians, deformation, ctx.scene, gts, ccfg["rule"], ccfg["threshold"])
        return {k: score.to_dict()[k] for k in ("miou", "macc", "pooled_iou")} | info

    return [ctx.cache.run("ceiling", key, work, ccfg)]
