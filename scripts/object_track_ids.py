"""Which track ids one object of a synthetic scene carries in each training view (docs/notes/competitors.md).

A classifier of identities (Gaussian Grouping, SA4D) learns what the ids say. This prints, for
every training view in time order, the share of the object's pixels (instance maps) under its two
most frequent ids of a tracks stage's folder, and each id's object (the object that holds most of
the track's pixels over the sequence, ``masks.tracked.track_objects``): where an
object's id is another object's track, a time-dependent identity field learns that object's
class at those times.

    python scripts/object_track_ids.py --dataset hypernerf --scene sel/hypernerf/synthetic \
        --tracks runs/.cache/tracks/<key> --object 6
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def object_ids(scene, tracks_dir: Path, obj: int) -> list[dict]:
    """One row per training view (time order): the object's top two ids with their shares of its
    pixels, and each id's object over the sequence."""
    from masks.generate import read_instance_map
    from masks.tracked import ids_path, load_ids, track_objects

    views = sorted(scene.train, key=lambda v: (float(v.camera.time), v.name))
    maps = [load_ids(ids_path(tracks_dir, v.name)) for v in views]  # [H, W] track ids, 0 = no track
    truths = [read_instance_map(scene.truth.instance_maps[v.name]) for v in views]  # [H, W] instance ids
    object_of = track_objects(maps, truths)  # {track id: its object over the sequence}
    rows = []
    for v, ids, truth in zip(views, maps, truths):
        mine = ids[truth == obj]
        row = {"view": v.name, "time": round(float(v.camera.time), 4), "pixels": int(mine.size), "ids": []}
        if mine.size:
            values, counts = np.unique(mine, return_counts=True)
            for k in np.argsort(-counts, kind="stable")[:2]:
                tid = int(values[k])
                row["ids"].append({"id": tid, "share": round(float(counts[k]) / mine.size, 3),  # 0: no track
                                   "object_of_track": object_of.get(tid)})
        rows.append(row)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--scene", type=Path, required=True, help="a synthetic scene folder (trase-bench synth)")
    ap.add_argument("--tracks", type=Path, required=True, help="a tracks stage's folder (<cache>/tracks/<key>)")
    ap.add_argument("--object", type=int, required=True, help="the object's instance id")
    args = ap.parse_args(argv)
    from benchmark.datasets import load_scene

    scene = load_scene(args.dataset, args.scene)
    if scene.truth is None:
        ap.error(f"{args.scene}: not a synthetic scene (no instance maps)")
    for row in object_ids(scene, args.tracks, args.object):
        print(json.dumps(row))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
