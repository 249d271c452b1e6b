"""Measure the classical tracker against the synthetic truth (docs/tracked-masks.md's figures).

For each format: the synthetic scene of the given seed and size (generated under --root if
absent), its synthetic anything masks (masks.seed 0, the benchmark's default generator on
synthetic scenes), its ground-truth geometry, then ``track_classical``; prints the agreement
with the instance maps (masks.tracked.agreement) and the time taken, one JSON line a format.

    python scripts/measure_tracking.py --seed 1 --size small --root /tmp/scenes
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path


def measure(dataset: str, seed: int, size: str, root: Path, **tracker) -> dict:
    import masks as masklib
    from benchmark.datasets import load_scene
    from benchmark.datasets.synthetic import generate
    from benchmark.pipeline.context import load_geometry
    from benchmark.pipeline.masks import make_mask_generator
    from benchmark.pipeline.settings import MaskSettings
    from benchmark.pipeline.tracks import track_classical

    scene_dir = root / f"{dataset}-s{seed}-{size}"
    if not (scene_dir / "synthetic" / "manifest.json").is_file():
        generate(dataset, scene_dir, seed=seed, size=size)
    scene = load_scene(dataset, scene_dir)
    truth = scene.truth
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        masklib.generate_scene_masks(scene.train, make_mask_generator(MaskSettings(generator="synthetic")), out,
                                     progress=False, instance_maps=dict(truth.instance_maps))
        gdir = out / "geometry"
        gdir.mkdir()
        (gdir / "geometry.npz").symlink_to(truth.geometry_path)
        gaussians, deformation = load_geometry(gdir)
        t0 = time.perf_counter()
        info = track_classical(scene.train, gaussians, deformation, out, truth=truth, **tracker)
        seconds = time.perf_counter() - t0
    return {"dataset": dataset, "seed": seed, "size": size, "views": len(scene.train), "seconds": round(seconds, 2),
            **info}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--size", default="small")
    ap.add_argument("--root", type=Path, default=Path("synthetic-scenes"))
    ap.add_argument("--datasets", default="nerfds,hypernerf,neu3d,immersive,technicolor")
    ap.add_argument("--memory", type=int, default=None, help="earlier views a lost track is sought in (default: the stage's)")
    ap.add_argument("--no-parts", action="store_true", help="segments inside a track start their own")
    ap.add_argument("--no-same-camera", action="store_true", help="a rig's camera's own latest view is not sought")
    args = ap.parse_args(argv)
    tracker = {**({"memory": args.memory} if args.memory is not None else {}),
               **({"part_of_share": None} if args.no_parts else {}),
               **({"same_camera": False} if args.no_same_camera else {})}
    for d in args.datasets.split(","):
        print(json.dumps(measure(d, args.seed, args.size, args.root, **tracker)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
