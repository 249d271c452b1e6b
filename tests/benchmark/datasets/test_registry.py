import csv
from pathlib import Path

import pytest

from benchmark.datasets import DATASETS, DatasetError, get_dataset, nerfies_time

PUBLISHED = Path("/work/shared/published/trase_paper_per_sequence.csv")


def test_five_benchmarks_with_display_names():
    assert list(DATASETS) == ["nerfds", "hypernerf", "neu3d", "immersive", "technicolor"]
    assert [s.display_name for s in DATASETS.values()] == [
        "NeRF-DS-Mask", "HyperNeRF-Mask", "Neu3D-Mask", "Immersive-Mask", "Technicolor-Mask"]


@pytest.mark.skipif(not PUBLISHED.exists(), reason="published per-sequence table not present")
def test_sequences_match_paper_table():
    rows = list(csv.DictReader(PUBLISHED.open()))
    for key, spec in DATASETS.items():
        paper = {r["sequence"] for r in rows if r["dataset"] == key and not r["sequence"].startswith("_")}
        assert paper == set(spec.sequences), key


def test_reconstruction_schedule_and_rig():
    d = DATASETS
    assert [(d[k].warm_up, d[k].densify_until) for k in d] == [
        (3000, 15000), (1500, 9000), (3000, 8000), (1000, 3000), (3000, 5000)]
    assert [d[k].monocular for k in d] == [True, True, False, False, False]


def test_frame_ranges():
    t = DATASETS["technicolor"]
    assert t.frames("Birthday")[0] == 151 and t.frames("Birthday")[-1] == 200
    assert t.frames("Painter") == list(range(100, 150))
    assert len(DATASETS["neu3d"].frames("sear_steak")) == 300
    assert DATASETS["immersive"].frames("02_Flames") == list(range(50))


def test_time_rules():
    n3 = DATASETS["neu3d"]
    assert n3.time_of(0, 300) == 0.0 and n3.time_of(150, 300) == 0.5
    with pytest.raises(DatasetError):
        n3.time_of(300, 300)
    with pytest.raises(DatasetError):
        DATASETS["nerfds"].time_of(0, 10)
    assert nerfies_time(3, 6) == 0.5 and nerfies_time(0, 0) == 0.0


def test_unknown_names_list_valid_ones():
    with pytest.raises(DatasetError, match="valid: nerfds, hypernerf"):
        get_dataset("dnerf")
    with pytest.raises(DatasetError, match="americano"):
        DATASETS["hypernerf"].resolve_sequence("vrig-chicken")
    assert get_dataset("Immersive-Mask").resolve_sequence("10_Alexa_Meade_Face_Paint_1") == "10_Alexa_1"


def test_to_dict_is_json():
    import json

    json.dumps({k: s.to_dict() for k, s in DATASETS.items()})


def test_find_scene_dir_nested_and_alias(tmp_path):
    from benchmark.datasets import find_gt_dir, find_scene_dir

    (tmp_path / "hypernerf" / "interp" / "chickchicken").mkdir(parents=True)
    (tmp_path / "immersive" / "10_Alexa_Meade_Face_Paint_1").mkdir(parents=True)
    assert find_scene_dir("hypernerf", "chickchicken", tmp_path) == tmp_path / "hypernerf" / "interp" / "chickchicken"
    assert find_scene_dir("immersive", "10_Alexa_1", tmp_path).name == "10_Alexa_Meade_Face_Paint_1"
    assert find_scene_dir("neu3d", "sear_steak", tmp_path) is None
    gt = tmp_path / "Immersive-Mask" / "10_Alexa_1" / "gt_masks"
    gt.mkdir(parents=True)
    assert find_gt_dir("immersive", "10_Alexa_1", tmp_path) == gt
    scene = tmp_path / "immersive" / "10_Alexa_Meade_Face_Paint_1"
    assert find_gt_dir("immersive", "10_Alexa_1", scene_dir=scene) == gt  # data root inferred
    with pytest.raises(DatasetError, match="unknown sequence"):
        find_scene_dir("neu3d", "flame_salmon", tmp_path)
