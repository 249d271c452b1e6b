"""Clustering agreement between seeds: id maps, ARI per gaussian and per pixel."""

import types

import cv2
import numpy as np
import pytest

from benchmark.results.stability import (
    CHUNK,
    cluster_id_map,
    gaussian_ari,
    geometry_checksum,
    pixel_ari,
    save_cluster_maps,
    seed_agreement,
    seed_summary,
)
from tests.trase.helpers import exact_masks, tiny_scene


def test_cluster_id_map_is_the_dominant_cluster_and_chunks_agree(monkeypatch):
    gm, deform, ids, views = tiny_scene()
    v = views[1]
    got = cluster_id_map(gm, deform, ids, v.camera)
    want = exact_masks(gm, deform, ids, v).masks  # per object: alpha >= 0.5, dominant object
    assert got.shape == (v.camera.height, v.camera.width) and len(want) == 2
    assert set(np.unique(got)) == {-1, 0, 1}
    for obj in (0, 1):
        assert np.array_equal(got == obj, want[obj])
    # many clusters, rendered CHUNK at a time: the same map up to the renaming
    fine = ids * 40 + np.arange(ids.size) % 40  # 80 clusters, 3 chunks
    fine_map = cluster_id_map(gm, deform, fine, v.camera)
    coarse = np.where(fine_map >= 0, fine_map // 40, -1)
    assert CHUNK < 80 and ((coarse == got).mean() > 0.97)
    assert (cluster_id_map(gm, deform, ids[:0], v.camera) == -1).all()  # no clusters: no surface


def test_ari_per_gaussian_and_pixel(tmp_path):
    gm, deform, ids, views = tiny_scene()
    cams = {f"{i:05d}": view.camera for i, view in enumerate(views[:2])}
    fitted = types.SimpleNamespace(gaussians=gm, deformation=deform, labels=ids)
    renamed = types.SimpleNamespace(gaussians=gm, deformation=deform, labels=1 - ids)
    split = types.SimpleNamespace(gaussians=gm, deformation=deform,
                                  labels=np.arange(ids.size) % 2)  # unrelated to the objects
    maps = {name: tmp_path / name / "clusters" for name in "abc"}  # as in a run directory
    for name, f in (("a", fitted), ("b", renamed), ("c", split)):
        save_cluster_maps(maps[name], f, cams)
    assert gaussian_ari(maps["a"], maps["b"]) == pytest.approx(1.0)  # renaming only
    assert pixel_ari(maps["a"], maps["b"]) == pytest.approx(1.0)
    assert abs(gaussian_ari(maps["a"], maps["c"])) < 0.05
    assert pixel_ari(maps["a"], maps["c"]) < 0.5
    ids_png = cv2.imread(str(maps["a"] / "ids_00000.png"), cv2.IMREAD_UNCHANGED)
    assert ids_png.dtype == np.uint16 and ids_png.max() == 2  # 0 = no surface

    def rec(seed, name, geo="g1"):
        return {"run": {"seed": seed, "group": "x"}, "_dir": str(tmp_path / name), "geometry_checksum": geo,
                "metrics": {"official": {"miou": 0.5 + 0.1 * seed}}, "oracle": None, "ceiling": {"miou": 0.9}}

    ag = seed_agreement([rec(1, "b"), rec(0, "a")])
    assert ag["pairs"][0]["seeds"] == [0, 1] and ag["gaussian_ari"] == pytest.approx(1.0)
    other_geometry = seed_agreement([rec(0, "a"), rec(1, "c", "g2")])
    assert other_geometry["gaussian_ari"] is None and other_geometry["pixel_ari"] is not None
    assert seed_agreement([rec(0, "a")]) is None
    s = seed_summary([rec(0, "a"), rec(1, "b"), rec(2, "c")])
    assert s["miou"]["mean"] == pytest.approx(0.6) and s["miou"]["std"] == pytest.approx(0.1) and s["miou"]["n"] == 3
    assert s["oracle"] is None and s["ceiling"]["std"] == pytest.approx(0.0)
    assert geometry_checksum(gm) == geometry_checksum(tiny_scene()[0]) != geometry_checksum(tiny_scene(seed=1)[0])
