"""scripts/object_track_ids.py: the ids one object of a synthetic scene carries, view by view."""

import runpy
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "object_track_ids.py"


@pytest.fixture(scope="module")
def scene_and_tracks(tmp_path_factory):
    from benchmark.datasets import load_scene
    from benchmark.datasets.synthetic import generate
    from benchmark.pipeline.tracks import write_synthetic

    root = tmp_path_factory.mktemp("ids")
    scene = load_scene("hypernerf", generate("hypernerf", root / "scene", seed=0, size="tiny"))
    write_synthetic(scene, root / "tracks")  # ids from the instance maps: one track per object
    return scene, root / "tracks"


def test_an_object_under_its_own_track_and_under_another_objects(scene_and_tracks, tmp_path):
    import shutil

    from masks.generate import read_instance_map
    from masks.tracked import ids_path, load_ids, save_ids

    scene, tracks = scene_and_tracks
    object_ids = runpy.run_path(str(SCRIPT))["object_ids"]
    first = scene.train[0]
    truth = read_instance_map(scene.truth.instance_maps[first.name])
    objects, counts = np.unique(truth[truth > 0], return_counts=True)
    obj, other = (int(o) for o in objects[np.argsort(-counts)][:2])
    rows = object_ids(scene, tracks, obj)
    assert [r["view"] for r in rows] == [v.name for v in sorted(scene.train, key=lambda v: (v.camera.time, v.name))]
    seen = [r for r in rows if r["pixels"]]
    assert seen and all(r["ids"][0]["share"] == 1.0 and r["ids"][0]["object_of_track"] == obj for r in seen)

    # the object given the other object's track in the first view (a mask that merged the two)
    bad = Path(shutil.copytree(tracks, tmp_path / "bad"))
    ids = load_ids(ids_path(bad, first.name))
    other_id = int(np.bincount(ids[truth == other]).argmax())
    ids[truth == obj] = other_id
    save_ids(ids_path(bad, first.name), ids)
    row = next(r for r in object_ids(scene, bad, obj) if r["view"] == first.name)
    assert row["ids"] == [{"id": other_id, "share": 1.0, "object_of_track": other}]
