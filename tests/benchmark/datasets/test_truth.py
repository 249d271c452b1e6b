"""The synthetic scenes' truth: one reader of synthetic/manifest.json, typed fields, clear errors."""

import json

import pytest

from benchmark.datasets import load_scene
from benchmark.datasets.errors import DatasetError
from benchmark.datasets.synthetic import generate
from benchmark.datasets.truth import SCENE_INFO_KEYS, read_truth, write_manifest
from trase.checkpoint import load_tabulated_geometry


def test_generated_scene_carries_its_truth(tmp_path):
    root = tmp_path / "s"
    generate("hypernerf", root, seed=0, size="tiny")
    scene = load_scene("hypernerf", root)
    truth = scene.truth
    assert scene.variant == "synthetic" and truth is not None
    assert set(truth.info) == set(SCENE_INFO_KEYS) and truth.info["seed"] == 0 and truth.info["size"] == "tiny"
    assert truth.interest_ids and set(truth.interest_ids) < {o.id for o in truth.objects}
    names = {o.id: o.name for o in truth.objects}
    assert sorted(names[i] for i in truth.mover_ids) == ["cube", "pillar"]  # moving, not of interest
    assert truth.n_ids == max(o.id for o in truth.objects) + 1
    assert {v.name for v in scene.train} <= set(truth.instance_maps)
    assert all(p.is_file() for p in truth.instance_maps.values())
    g, _, ids = load_tabulated_geometry(truth.geometry_path)
    assert g.num_gaussians == len(ids) > 0


def test_bad_manifests_name_the_file(tmp_path):
    path = tmp_path / "synthetic" / "manifest.json"
    path.parent.mkdir()
    path.write_text("{not json")
    with pytest.raises(DatasetError, match=r"manifest.json: cannot read the synthetic manifest"):
        read_truth(path)
    path.write_text("[]")
    with pytest.raises(DatasetError, match=r"manifest.json: the synthetic manifest is not a JSON object"):
        read_truth(path)
    path.write_text(json.dumps({"objects": [{"name": "ball"}]}))
    with pytest.raises(DatasetError, match=r"manifest.json: synthetic manifest: malformed objects"):
        read_truth(path)


def test_written_manifest_reads_back(tmp_path):
    path = write_manifest(tmp_path, {"seed": 3, "objects": [{"id": 1, "name": "a"}, {"id": 4, "name": "b"}],
                                     "objects_of_interest": ["b"], "instances": {"cam/0": "instances/x.png"}})
    truth = read_truth(path)
    assert truth.interest_ids == [4] and truth.n_ids == 5 and truth.info["seed"] == 3
    assert truth.mover_ids == []  # no object says how it moves
    assert truth.instance_maps == {"cam/0": tmp_path / "synthetic" / "instances" / "x.png"}
    assert truth.geometry_path == tmp_path / "synthetic" / "geometry.npz"


def test_movers_are_the_moving_objects_not_of_interest(tmp_path):
    objects = [{"id": 1, "name": "wall", "motion": "static"}, {"id": 2, "name": "ball", "motion": "rigid"},
               {"id": 3, "name": "pillar", "motion": "rigid"}, {"id": 4, "name": "blob", "motion": "deforming"}]
    truth = read_truth(write_manifest(tmp_path, {"objects": objects, "objects_of_interest": ["ball"]}))
    assert truth.interest_ids == [2] and truth.mover_ids == [3, 4]
    assert [o.motion for o in truth.objects] == ["static", "rigid", "rigid", "deforming"]
