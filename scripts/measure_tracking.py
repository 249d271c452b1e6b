"""Measure the classical tracker against the synthetic truth (docs/tracked-masks.md's figures).

For each format: the synthetic scene of the given seed and size (generated under --root if
absent), its synthetic anything masks (masks.seed 0, the benchmark's default generator on
synthetic scenes), its ground-truth geometry (or a geometry stage's folder, ``--geometry``, for a
reconstruction), then ``track_classical``; prints the agreement
with the instance maps (masks.tracked.agreement) and the time taken, one JSON line a format.

    python scripts/measure_tracking.py --seed 1 --size small --root /tmp/scenes
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path


def merge_sweep(scene, masks_dir: Path, votes, n_tracks: int, cosines: list[float], togethers: list[float]) -> dict:
    """{"<cosine>/<max together>": agreement} of the unmerged tracks in ``masks_dir`` merged with
    each pair of settings."""
    from masks.generate import read_instance_map
    from masks.track_merging import merged_ids, track_similarity
    from masks.tracked import agreement, ids_path, load_ids

    maps = [load_ids(ids_path(masks_dir, v.name)) for v in scene.train]
    truth = [read_instance_map(scene.truth.instance_maps[v.name]) for v in scene.train]
    matrix, shown = votes.matrices(n_tracks)
    similarity = track_similarity(matrix)
    out = {}
    for c in cosines:
        for m in togethers:
            new_id = merged_ids(similarity, shown, c, m)
            out[f"{c}/{m}"] = agreement([new_id[ids] for ids in maps], truth)
    return out


def measure(dataset: str, seed: int, size: str, root: Path, sweep: tuple = (), geometry: Path | None = None,
            **tracker) -> dict:
    import masks as masklib
    from benchmark.datasets import load_scene
    from benchmark.datasets.synthetic import generate
    from benchmark.pipeline.classical_tracker import track_classical
    from benchmark.pipeline.context import load_geometry
    from benchmark.pipeline.masks import make_mask_generator
    from benchmark.pipeline.settings import MaskSettings
    from masks.track_merging import TrackVotes

    scene_dir = root / f"{dataset}-s{seed}-{size}"
    if not (scene_dir / "synthetic" / "manifest.json").is_file():
        generate(dataset, scene_dir, seed=seed, size=size)
    scene = load_scene(dataset, scene_dir)
    truth = scene.truth
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        masklib.generate_scene_masks(scene.train, make_mask_generator(MaskSettings(generator="synthetic")), out,
                                     progress=False, instance_maps=dict(truth.instance_maps))
        gdir = geometry
        if gdir is None:  # the scene's ground truth, as a geometry stage's folder
            gdir = out / "geometry"
            gdir.mkdir()
            (gdir / "geometry.npz").symlink_to(truth.geometry_path)
        gaussians, deformation = load_geometry(gdir)
        t0 = time.perf_counter()
        votes = TrackVotes(gaussians.num_gaussians) if sweep else None
        info = track_classical(scene.train, gaussians, deformation, out, truth=truth, votes=votes, **tracker)
        seconds = time.perf_counter() - t0
        if sweep:  # the same tracks merged with each pair of settings
            info["merge_sweep"] = merge_sweep(scene, out, votes, info["n_tracks"], *sweep)
    return {"dataset": dataset, "seed": seed, "size": size, "views": len(scene.train), "seconds": round(seconds, 2),
            "geometry": "ground truth" if geometry is None else str(geometry), **info}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--size", default="small")
    ap.add_argument("--root", type=Path, default=Path("synthetic-scenes"))
    ap.add_argument("--datasets", default="nerfds,hypernerf,neu3d,immersive,technicolor")
    ap.add_argument("--memory", type=int, default=None, help="earlier views a lost track is sought in (default: the stage's)")
    ap.add_argument("--no-parts", action="store_true", help="segments inside a track start their own")
    ap.add_argument("--no-same-camera", action="store_true", help="a rig's camera's own latest view is not sought")
    ap.add_argument("--merge-cosine", type=float, default=None, help="merge tracks this similar (default: the stage's)")
    ap.add_argument("--no-merge", action="store_true", help="tracks that are one object in 3D are not merged")
    ap.add_argument("--no-carry", action="store_true", help="a track no segment continues is not carried on")
    ap.add_argument("--geometry", type=Path, default=None,
                    help="a geometry stage's folder (one dataset only; default: the scene's ground truth)")
    ap.add_argument("--merge-sweep", default="", help="with --no-merge: the agreement of the same tracks merged at "
                                                      "each of these cosines (comma-separated)")
    ap.add_argument("--together-sweep", default="0", help="with --merge-sweep: ... and each of these shares of "
                                                          "views two tracks may share (comma-separated)")
    args = ap.parse_args(argv)
    tracker = {**({"memory": args.memory} if args.memory is not None else {}),
               **({"part_of_share": None} if args.no_parts else {}),
               **({"same_camera": False} if args.no_same_camera else {}),
               **({"merge_cosine": args.merge_cosine} if args.merge_cosine is not None else {}),
               **({"merge_cosine": None} if args.no_merge else {}),
               **({"carry": 0} if args.no_carry else {})}
    cosines = [float(c) for c in args.merge_sweep.split(",") if c]
    if cosines and not args.no_merge:
        ap.error("--merge-sweep merges the tracks of one unmerged pass: give --no-merge too")
    sweep = (cosines, [float(m) for m in args.together_sweep.split(",") if m]) if cosines else ()
    datasets = args.datasets.split(",")
    if args.geometry is not None and len(datasets) != 1:
        ap.error("--geometry is one scene's: give one dataset")
    for d in datasets:
        print(json.dumps(measure(d, args.seed, args.size, args.root, sweep=sweep, geometry=args.geometry, **tracker)),
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
