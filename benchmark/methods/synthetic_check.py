"""End-to-end check of a method on a synthetic scene with ground-truth geometry:
synthetic noisy masks -> features -> clusters -> GT-derived prompts -> segmentation -> score.

    python -m benchmark.methods.synthetic_check --dataset nerfds [--method trase]
        [--iterations 1500] [--size small] [--work DIR] [--json]

Prints mIoU (v1) for the prompted selection and, separately, for the oracle selection (an
upper bound, never the method's score), plus timings. Uses the synthetic scene cache
($TRASE_CACHE), generating the scene on first use.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path


def run_check(dataset: str, method_name: str = "trase", size: str = "small", iterations: int | None = None,
              work: Path | None = None, progress: bool = True, overrides: dict | None = None) -> dict:
    import masks as masklib
    from benchmark.datasets import get_dataset, load_scene
    from benchmark.datasets.synthetic.cache import ensure_synthetic
    from benchmark.io import read_json
    from benchmark.methods import get_method
    from benchmark.scoring import read_mask, score_masks
    from masks.generators.base import make_generator
    from trase.checkpoint import load_synthetic_geometry
    from trase.prompts import load_or_make_prompts

    t_all = time.perf_counter()
    scene_dir = ensure_synthetic(dataset, size=size)
    scene = load_scene(dataset, scene_dir, gt_dir=scene_dir / "gt_masks")
    spec = get_dataset(dataset)
    gaussians, deformation, _ = load_synthetic_geometry(scene_dir / "synthetic" / "geometry.npz")
    work = Path(work) if work is not None else Path(tempfile.mkdtemp(prefix=f"check-{dataset}-"))
    work.mkdir(parents=True, exist_ok=True)

    # synthetic noisy masks from the instance maps (the runner's masks stage does the same)
    manifest_path = scene_dir / "synthetic" / "manifest.json"
    manifest = read_json(manifest_path, "synthetic manifest")
    inst = {name: manifest_path.parent / rel for name, rel in manifest["instances"].items()}
    masks_dir = work / "masks"
    t0 = time.perf_counter()
    masklib.generate_scene_masks(scene.train, make_generator("synthetic", seed=0), masks_dir,
                                 progress=False, instance_maps=inst)
    t_masks = time.perf_counter() - t0

    method = get_method(method_name)
    cfg = method.default_config(spec)
    if iterations is not None:
        cfg["features"]["iterations"] = int(iterations)
    for k, v in (overrides or {}).items():
        section, _, key = k.partition(".")
        if key:
            cfg[section][key] = v
        else:
            cfg[section] = v
    fitted = method.fit(scene, gaussians, deformation, masks_dir, cfg, work / "fit", progress=progress)

    gts = [read_mask(p) for p in scene.gt_masks]
    prompts = load_or_make_prompts(work / "prompts.json", scene.test, lambda i: gts[i])
    t0 = time.perf_counter()
    preds = method.segment(fitted, scene, prompts)
    t_seg = time.perf_counter() - t0
    names = [f"{i:05d}" for i in range(len(scene.test))]
    score = score_masks(dict(zip(names, preds)), dict(zip(names, gts)), metric="v1")
    out = {
        "dataset": dataset, "method": method_name, "size": size,
        "n_gaussians": int(gaussians.num_gaussians), "n_train": len(scene.train), "n_test": len(scene.test),
        "miou": score.miou, "macc": score.macc,
        "selected_clusters": fitted.stats.get("selected_clusters"),
        "n_clusters": fitted.stats["n_clusters"], "kept_fraction": fitted.stats["kept_fraction"],
        "feature_space": fitted.stats["feature_space"],
        "fastpath_bytes_per_view": fitted.stats["path"].get("bytes_per_view_mean"),
        "timings": {**fitted.timings, "masks": t_masks, "segment": t_seg},
        "iterations": cfg["features"]["iterations"],
        "n_clicks": len(prompts.clicks),
    }
    if hasattr(method, "segment_oracle"):
        opreds, oclusters = method.segment_oracle(fitted, scene, gts)
        oscore = score_masks(dict(zip(names, opreds)), dict(zip(names, gts)), metric="v1")
        out["oracle_miou"] = oscore.miou
        out["oracle_clusters"] = oclusters
    out["timings"]["total"] = time.perf_counter() - t_all
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dataset", default="nerfds")
    ap.add_argument("--method", default="trase")
    ap.add_argument("--size", default="small")
    ap.add_argument("--iterations", type=int, default=None)
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--set", action="append", default=[], help="section.key=json_value")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    overrides = {}
    for s in a.set:
        k, _, v = s.partition("=")
        try:
            overrides[k] = json.loads(v)
        except json.JSONDecodeError:
            overrides[k] = v
    res = run_check(a.dataset, a.method, a.size, a.iterations, a.work, progress=sys.stderr.isatty(),
                    overrides=overrides)
    if a.json:
        print(json.dumps(res, default=float))
    else:
        print(f"{res['dataset']}: mIoU {res['miou']:.4f}  mAcc {res['macc']:.4f}  "
              f"(oracle mIoU {res.get('oracle_miou', float('nan')):.4f}, not a score)  "
              f"clusters {res['n_clusters']}, selected {res['selected_clusters']}, "
              f"kept {res['kept_fraction']:.3f}; train {res['timings']['features_train']:.1f}s "
              f"for {res['iterations']} it, total {res['timings']['total']:.1f}s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
