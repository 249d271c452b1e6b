"""The results record of one sequence (benchmark.results.RunRecord), from the resolved config
and the stage records: scores, oracle and model facts come from the evaluate stage's info,
the ceiling from its stage."""

from __future__ import annotations

from pathlib import Path

from benchmark.io import sha256_files
from benchmark.pipeline.ceiling import NOTE as CEILING_NOTE
from benchmark.pipeline.context import SequenceRun, jsonable
from benchmark.results import RunRecord

V1_KEYS = ("miou", "macc", "pooled_iou", "metric", "metric_version", "n_frames", "both_empty", "missing")
OFFICIAL_KEYS = ("miou", "macc", "pooled_iou", "metric_version")


def build_record(ctx: SequenceRun, run: dict, dataset: str, variant: str, scene_dir: Path, config_hash: str,
                 prompts: dict, run_dir: Path) -> RunRecord:
    scene, settings = ctx.scene, ctx.settings
    method = settings.method
    ev = ctx.records["evaluate"].info
    ceiling = ctx.records["ceiling"].info if "ceiling" in ctx.records else None
    v1, official = ev["v1"], ev["official"]
    pred_files = sorted((run_dir / "pred").glob("*.png"))
    return RunRecord(
        run=run, method=ctx.method.name, dataset=dataset, sequence=scene.sequence, variant=variant,
        synthetic_scene=dict(scene.truth.info) if scene.truth else None,
        metrics={**{k: v1[k] for k in V1_KEYS}, "official": {k: official[k] for k in OFFICIAL_KEYS}},
        per_frame=v1["per_frame"],
        oracle=ev["oracle"], corrective=ev.get("corrective"), text=ev.get("text"),
        ceiling=(ceiling | {"note": CEILING_NOTE}) if ceiling else None,
        stages={name: r.to_dict() for name, r in ctx.records.items()},
        n_gaussians=ev["n_gaussians"], n_clusters=ev["n_clusters"],
        selected_clusters=ev["selected"], click_clusters=ev["click_clusters"], click_sets=ev["click_sets"],
        feature_space=ev["feature_space"], geometry_checksum=ev["geometry_checksum"], storage=ev["storage"],
        config=jsonable(settings.to_dict()), config_hash=config_hash,
        seeds={"run": settings.seed, "masks": settings.masks.seed, "geometry": settings.geometry.train.seed,
               "features": getattr(getattr(method, "features", None), "seed", None),
               "clustering": getattr(getattr(method, "clustering", None), "seed", None)},
        checksums={"gt": ctx.gt_key, "pred": sha256_files(pred_files)[:16]},
        prompts=prompts, scene_dir=str(Path(scene_dir).resolve()),
        frames=[{"frame": f"{i:05d}", "view": v.name, "image": str(v.image_path), "gt": str(scene.gt_masks[i]),
                 "pred": f"pred/{i:05d}.png"} for i, v in enumerate(scene.test)],
    )
