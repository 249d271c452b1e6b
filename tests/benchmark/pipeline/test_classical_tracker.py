"""The classical tracker (benchmark.pipeline.classical_tracker) on the tiny scene's ground-truth
geometry: agreement with the instance maps, a fixed camera's own latest view, tracks merged
back, an object carried through a merged mask."""

import shutil
import types

import numpy as np
import pytest

from masks.generate import read_instance_map
from masks.tracked import agreement, ids_path, load_ids, load_tracks_info


def _truth_maps(scene):
    return [read_instance_map(scene.truth.instance_maps[v.name]) for v in scene.train]


def test_the_classical_tracker_on_ground_truth_geometry(tiny_scene, tmp_path):
    """Synthetic anything masks (split, merged, jittered) of the tiny scene's training views,
    tracked through its ground-truth geometry; agreement with the instance maps measured."""
    import masks as masklib
    from benchmark.pipeline.classical_tracker import time_order, track_classical
    from benchmark.pipeline.context import load_geometry
    from masks.generators.synthetic import SyntheticGenerator

    scene = tiny_scene
    masklib.generate_scene_masks(scene.train, SyntheticGenerator(seed=0), tmp_path, progress=False,
                                 instance_maps=dict(scene.truth.instance_maps))
    geo = tmp_path / "geometry"
    geo.mkdir()
    shutil.copyfile(scene.truth.geometry_path, geo / "geometry.npz")
    gaussians, deformation = load_geometry(geo)
    info = track_classical(scene.train, gaussians, deformation, tmp_path, truth=scene.truth)
    stored = load_tracks_info(tmp_path)
    assert stored["source"] == "classical" and stored["n_tracks"] == info["n_tracks"] > 0
    maps = [load_ids(ids_path(tmp_path, v.name)) for v in scene.train]
    a = agreement(maps, _truth_maps(scene))
    assert a == stored["agreement_with_truth"]
    # measured: masks 1.0, pixels 0.908, 1.0 tracks per object (3 views, 12 tracked masks, 5 tracks)
    assert a["masks"] >= 0.9 and a["pixels"] >= 0.85 and a["tracks_per_object"] <= 2.0
    assert info["continued"] > 0  # ids carried from view to view, not all new
    order = time_order(scene.train)
    assert [v.camera.time for v in order] == sorted(v.camera.time for v in scene.train)
    # the ids cover exactly the segments: 0 where no mask is, a track elsewhere
    for v, ids in zip(scene.train, maps):
        covered = masklib.load(masklib.mask_path(tmp_path, v.name)).masks.any(0)
        assert not (ids[~covered] > 0).any()


@pytest.mark.parametrize("same_camera", [True, False])
def test_a_fixed_camera_finds_its_own_latest_view_when_the_previous_one_sees_nothing(tiny_scene, tmp_path,
                                                                                     same_camera):
    """A rig's views in time order: a (camera 1), b (camera 2, turned around: it shows other
    surfaces), c (camera 1 again, an instant later). With no memory, c's segments continue a's
    tracks (where b's do not) only through the same camera's latest view."""
    import dataclasses

    import masks as masklib
    from benchmark.pipeline.classical_tracker import camera_key, track_classical
    from benchmark.pipeline.context import load_geometry
    from masks.generators.synthetic import SyntheticGenerator

    first = tiny_scene.train[0]
    masklib.generate_scene_masks([first], SyntheticGenerator(seed=0), tmp_path, progress=False,
                                 instance_maps=dict(tiny_scene.truth.instance_maps))
    away = first.camera.w2c.copy()
    away[:3, :3] = -away[:3, :3] @ np.diag([1.0, 1.0, -1.0])  # turned around (a proper rotation)
    t0 = float(first.camera.time)
    views = [types.SimpleNamespace(name=n, camera=dataclasses.replace(first.camera, time=t0 + dt, w2c=w))
             for n, dt, w in (("a", 0.0, first.camera.w2c), ("b", 1e-6, away), ("c", 2e-6, first.camera.w2c))]
    for v in views:
        shutil.copyfile(masklib.mask_path(tmp_path, first.name), masklib.mask_path(tmp_path, v.name))
    assert camera_key(views[0].camera) == camera_key(views[2].camera) != camera_key(views[1].camera)
    geo = tmp_path / "geometry"
    geo.mkdir()
    shutil.copyfile(tiny_scene.truth.geometry_path, geo / "geometry.npz")
    gaussians, deformation = load_geometry(geo)
    info = track_classical(views, gaussians, deformation, tmp_path, memory=0, same_camera=same_camera,
                           merge_cosine=None)
    a, b, c = (load_ids(ids_path(tmp_path, n)) for n in "abc")
    assert a.max() > 0 and (b > a.max()).any()  # b sees other surfaces: tracks of its own
    known = max(a.max(), b.max())
    if same_camera:  # what b does not continue, a does: no new track
        assert c.max() <= known and info["resumed"] > 0 and np.isin(np.unique(c[c > 0]), np.unique(a)).any()
    else:  # only b to continue from: what b does not show starts again
        assert info["resumed"] == 0 and (c > known).any()


def test_tracks_restarted_on_the_same_gaussians_are_merged_back(tiny_scene, tmp_path):
    """One camera's views a, b, c in time order, b without a single mask (a missed view): with
    no memory and no same-camera step, c starts a new track for everything. Those fall on the
    gaussians a voted for, and no view shows one beside its twin, so the merge gives c a's ids;
    without it they stay new."""
    import dataclasses

    import masks as masklib
    from benchmark.pipeline.classical_tracker import track_classical
    from benchmark.pipeline.context import load_geometry
    from masks.generators.synthetic import SyntheticGenerator

    first = tiny_scene.train[0]
    masklib.generate_scene_masks([first], SyntheticGenerator(seed=0), tmp_path, progress=False,
                                 instance_maps=dict(tiny_scene.truth.instance_maps))
    t0 = float(first.camera.time)
    views = [types.SimpleNamespace(name=n, camera=dataclasses.replace(first.camera, time=t0 + dt))
             for n, dt in (("a", 0.0), ("b", 1e-6), ("c", 2e-6))]
    for n in "ac":
        shutil.copyfile(masklib.mask_path(tmp_path, first.name), masklib.mask_path(tmp_path, n))
    h, w = first.camera.height, first.camera.width
    masklib.save(masklib.mask_path(tmp_path, "b"), masklib.MaskSet.from_masks(np.zeros((0, h, w), bool)))
    geo = tmp_path / "geometry"
    geo.mkdir()
    shutil.copyfile(tiny_scene.truth.geometry_path, geo / "geometry.npz")
    gaussians, deformation = load_geometry(geo)
    kept = track_classical(views, gaussians, deformation, tmp_path, memory=0, same_camera=False, merge_cosine=None,
                           carry=0)
    a, c = load_ids(ids_path(tmp_path, "a")), load_ids(ids_path(tmp_path, "c"))
    assert a.max() > 0 and not np.isin(np.unique(c[c > 0]), np.unique(a)).any()  # all restarted
    info = track_classical(views, gaussians, deformation, tmp_path, memory=0, same_camera=False, carry=0)
    a, c = load_ids(ids_path(tmp_path, "a")), load_ids(ids_path(tmp_path, "c"))
    assert info["tracks_before"] == kept["n_tracks"] == 2 * a.max() and info["n_tracks"] == a.max()
    assert np.array_equal(a, c) and load_tracks_info(tmp_path)["n_tracks"] == info["n_tracks"]


@pytest.mark.parametrize("carry", [5, 0])
def test_an_object_merged_into_a_neighbours_mask_keeps_its_track(tiny_scene, tmp_path, carry):
    """One camera's views a, a2, b in time order; b's masks are a's with one object's mask merged
    into its neighbour's (one mask of both, as an anything mask sometimes is). The merged
    segment continues the neighbour's track; carried on (the stage's: the object's own masks held
    its track in two views), the object keeps its track on its pixels; not carried, they take
    the neighbour's."""
    import dataclasses

    import masks as masklib
    from benchmark.pipeline.classical_tracker import track_classical
    from benchmark.pipeline.context import load_geometry
    from masks.generators.synthetic import SyntheticGenerator

    first = tiny_scene.train[0]
    masklib.generate_scene_masks([first], SyntheticGenerator(seed=0), tmp_path, progress=False,
                                 instance_maps=dict(tiny_scene.truth.instance_maps))
    for n in ("a", "a2"):
        shutil.copyfile(masklib.mask_path(tmp_path, first.name), masklib.mask_path(tmp_path, n))
    m = masklib.load(masklib.mask_path(tmp_path, "a")).masks  # [N, H, W]
    area = m.reshape(m.shape[0], -1).sum(1)
    big = int(area.argmax())
    small = int(np.argsort(area)[len(area) // 2])  # a middle-sized object, well under the largest
    assert 0 < area[small] < 0.5 * area[big] and not (m[small] & m[big]).any()
    merged = np.concatenate([np.delete(m, [small, big], axis=0), (m[small] | m[big])[None]])
    masklib.save(masklib.mask_path(tmp_path, "b"), masklib.MaskSet.from_masks(merged))
    t0 = float(first.camera.time)
    views = [types.SimpleNamespace(name=n, camera=dataclasses.replace(first.camera, time=t0 + dt))
             for n, dt in (("a", 0.0), ("a2", 1e-6), ("b", 2e-6))]
    geo = tmp_path / "geometry"
    geo.mkdir()
    shutil.copyfile(tiny_scene.truth.geometry_path, geo / "geometry.npz")
    gaussians, deformation = load_geometry(geo)
    info = track_classical(views, gaussians, deformation, tmp_path, memory=0, same_camera=False,
                           merge_cosine=None, carry=carry)
    a, b = load_ids(ids_path(tmp_path, "a")), load_ids(ids_path(tmp_path, "b"))
    own, neighbour = np.bincount(a[m[small]]).argmax(), np.bincount(a[m[big]]).argmax()
    assert own != neighbour and np.bincount(b[m[big]]).argmax() == neighbour
    on_object = np.bincount(b[m[small]], minlength=a.max() + 1)
    if carry:
        assert info["carried"] >= 1 and on_object[own] >= 0.8 * m[small].sum()
    else:
        assert info["carried"] == 0 and on_object[neighbour] == m[small].sum()
