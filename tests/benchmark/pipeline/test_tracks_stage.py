"""The tracks stage (benchmark.pipeline.tracks): ids from the synthetic truth, from a tracker's
files (DEVA's layout), from the classical tracker; the masks.tracking setting and the protocol."""

import json
import shutil
import types
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from benchmark.config import ConfigError
from masks.generate import read_instance_map
from masks.tracked import TrackFileError, agreement, ids_path, load_ids, load_tracks_info


def _truth_maps(scene):
    return [read_instance_map(scene.truth.instance_maps[v.name]) for v in scene.train]


def _one_object_per_track(scene, folder):
    """{track id: the one instance id it covers}, over every training view."""
    seen: dict[int, set[int]] = {}
    for v, truth in zip(scene.train, _truth_maps(scene)):
        ids = load_ids(ids_path(folder, v.name))
        for k in np.unique(ids[ids > 0]):
            seen.setdefault(int(k), set()).update(np.unique(truth[ids == k]).tolist())
    assert all(len(s) == 1 for s in seen.values()), seen
    return {k: s.pop() for k, s in seen.items()}


def test_synthetic_ids_name_one_object_in_every_view(tiny_scene, tmp_path):
    from benchmark.pipeline.tracks import write_synthetic

    info = write_synthetic(tiny_scene, tmp_path)
    stored = load_tracks_info(tmp_path)
    assert info["source"] == stored["source"] == "synthetic-truth"
    of_track = _one_object_per_track(tiny_scene, tmp_path)
    assert stored["n_tracks"] == len(of_track) >= 3
    assert {int(k): v for k, v in stored["instance_of_track"].items()} == of_track
    # an object seen in several views carries one id in all of them
    views_of = {}
    for v in tiny_scene.train:
        for k in np.unique(load_ids(ids_path(tmp_path, v.name))):
            if k:
                views_of.setdefault(of_track[int(k)], set()).add(int(k))
    assert all(len(ks) == 1 for ks in views_of.values())
    assert sum(len(ks) for ks in views_of.values()) == len(of_track)


def _deva_folder(scene, root: Path, encoding: str) -> Path:
    """A DEVA-like output folder from the truth: Annotations/<image stem>.png, the object ids
    arbitrary (x 1000 + 300) in DEVA's RGB long-id encoding, or short ids (x 10) in one channel."""
    ann = root / "Annotations"
    ann.mkdir(parents=True)
    for v, truth in zip(scene.train, _truth_maps(scene)):
        if encoding == "rgb":
            ids = np.where(truth > 0, truth * 1000 + 300, 0)
            img = np.stack([ids % 256, ids // 256 % 256, ids // 65536], -1).astype(np.uint8)
            Image.fromarray(img, "RGB").save(ann / f"{Path(v.image_path).stem}.png")
        else:
            Image.fromarray((truth * 10).astype(np.uint8), "L").save(ann / f"{Path(v.image_path).stem}.png")
    (root / "pred.json").write_text("{}")
    return root


@pytest.mark.parametrize("encoding", ["rgb", "short"])
def test_files_in_devas_layout_give_the_same_tracks(tiny_scene, tmp_path, encoding):
    from benchmark.pipeline.tracks import write_files

    src = _deva_folder(tiny_scene, tmp_path / "deva", encoding)
    out = tmp_path / "out"
    out.mkdir()
    info = write_files(tiny_scene.train, src, out)
    stored = load_tracks_info(out)
    assert info["read_from"] == str(src / "Annotations") and stored["source"] == "files"
    of_track = _one_object_per_track(tiny_scene, out)
    scale, offset = (1000, 300) if encoding == "rgb" else (10, 0)
    assert {int(k): v for k, v in stored["id_in_files_of_track"].items()} == {k: i * scale + offset
                                                                              for k, i in of_track.items()}
    assert sorted(of_track) == list(range(1, stored["n_tracks"] + 1))


def test_files_errors_name_the_file(tiny_scene, tmp_path):
    from benchmark.pipeline.tracks import write_files

    src = _deva_folder(tiny_scene, tmp_path / "deva", "short")
    view = tiny_scene.train[1]
    stem = Path(view.image_path).stem
    missing = src / "Annotations" / f"{stem}.png"
    small = np.zeros((4, 4), np.uint8)
    Image.fromarray(small, "L").save(missing)
    with pytest.raises(TrackFileError, match=f"{stem}.png: ids are 4x4 but training view"):
        write_files(tiny_scene.train, src, tmp_path)
    missing.unlink()
    with pytest.raises(ConfigError, match=f"Annotations/.*no track ids for training view {view.name}"):
        write_files(tiny_scene.train, src, tmp_path)
    with pytest.raises(ConfigError, match="not a folder"):
        write_files(tiny_scene.train, tmp_path / "nowhere", tmp_path)


def test_the_classical_tracker_on_ground_truth_geometry(tiny_scene, tmp_path):
    """Synthetic anything masks (split, merged, jittered) of the tiny scene's training views,
    tracked through its ground-truth geometry; agreement with the instance maps measured."""
    import masks as masklib
    from benchmark.pipeline.context import load_geometry
    from benchmark.pipeline.tracks import time_order, track_classical
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
    from benchmark.pipeline.context import load_geometry
    from benchmark.pipeline.tracks import camera_key, track_classical
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
    from benchmark.pipeline.context import load_geometry
    from benchmark.pipeline.tracks import track_classical
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
    from benchmark.pipeline.context import load_geometry
    from benchmark.pipeline.tracks import track_classical
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


def test_the_gaussians_a_view_shows_lie_on_its_rendered_surface(tiny_scene, tmp_path):
    from benchmark.pipeline.context import load_geometry
    from trase.warp import DEPTH_TOLERANCE, view_geometry, visible_gaussians

    shutil.copyfile(tiny_scene.truth.geometry_path, tmp_path / "geometry.npz")
    gaussians, deformation = load_geometry(tmp_path)
    cam = tiny_scene.train[0].camera
    g = view_geometry(gaussians, deformation, cam)
    idx, rows, cols = visible_gaussians(g)
    assert 0 < idx.shape[0] < gaussians.num_gaussians and np.unique(idx).shape[0] == idx.shape[0]
    uv, z = cam.project(g.means[idx].numpy().astype(np.float64))
    assert np.array_equal(np.floor(uv[:, 0]).astype(int), cols) and np.array_equal(np.floor(uv[:, 1]).astype(int), rows)
    d = g.depth[rows, cols]
    assert (g.alpha[rows, cols] >= 0.5).all() and (np.abs(z - d) <= DEPTH_TOLERANCE * d).all()
    # a gaussian moved twice as far along its ray lies behind the surface: no longer shown
    import dataclasses

    centre = torch.as_tensor(cam.center, dtype=g.means.dtype)
    means = g.means.clone()
    means[idx[:10]] = centre + 2.0 * (means[idx[:10]] - centre)
    behind = visible_gaussians(dataclasses.replace(g, means=means))[0]
    assert not np.isin(idx[:10], behind).any() and np.isin(idx[10:], behind).all()


def test_a_warp_between_identical_views_is_the_identity(tiny_scene, tmp_path):
    from benchmark.pipeline.context import load_geometry
    from trase.warp import backward_warp, view_geometry

    shutil.copyfile(tiny_scene.truth.geometry_path, tmp_path / "geometry.npz")
    gaussians, deformation = load_geometry(tmp_path)
    cam = tiny_scene.train[0].camera
    g = view_geometry(gaussians, deformation, cam)
    labels = np.arange(cam.height * cam.width).reshape(cam.height, cam.width)
    warped = backward_warp(gaussians, deformation, g, g, labels)
    known = warped >= 0
    assert known.mean() > 0.5
    assert (warped[known] == labels[known]).mean() > 0.99


# -- settings and protocol ---------------------------------------------------------------------
def _settings(method="trase", variant="synthetic", **sets):
    from benchmark.config import parse_overrides
    from benchmark.datasets import get_dataset
    from benchmark.methods import get_method
    from benchmark.pipeline.settings import run_settings

    m = get_method(method) if isinstance(method, str) else method
    ov = parse_overrides([f"{k}={v}" for k, v in sets.items()] + ["geometry.train.device=cpu",
                                                                  "method.features.device=cpu"])
    return run_settings(m, get_dataset("hypernerf"), variant, ov, (160, 120))


def test_tracking_none_is_not_recorded_and_other_values_are():
    from benchmark.results.runs import protocol, protocol_label

    plain = _settings()
    assert "tracking" not in plain.to_dict()["masks"] and plain.masks.tracking == "none"
    assert "tracks" not in protocol({"config": plain.to_dict()})
    explicit = _settings(**{"masks.tracking": "none"})
    assert explicit.to_dict() == plain.to_dict() and explicit.group_hash == plain.group_hash
    syn = _settings(**{"masks.tracking": "synthetic"})
    assert syn.to_dict()["masks"]["tracking"] == "synthetic" and syn.group_hash != plain.group_hash
    assert "tracks tracked from ground truth" in protocol_label(protocol({"config": syn.to_dict()}))
    files = _settings(**{"masks.tracking": "files", "masks.tracks_dir": "/x"})
    assert "tracked ids from files" in protocol_label(protocol({"config": files.to_dict()}))


def test_tracking_settings_that_cannot_work_stop_the_run():
    from benchmark.methods import get_method

    with pytest.raises(ConfigError, match="choose none, synthetic, files, classical"):
        _settings(**{"masks.tracking": "deva"})
    with pytest.raises(ConfigError, match="needs --set masks.tracks_dir"):
        _settings(**{"masks.tracking": "files"})
    with pytest.raises(ConfigError, match="tracks_dir: read only with masks.tracking=files"):
        _settings(**{"masks.tracks_dir": "/x"})
    with pytest.raises(ConfigError, match="this scene is real"):
        _settings(variant="real", **{"masks.tracking": "synthetic"})
    needy = get_method("trase")
    needy.needs_tracks = True  # a method that learns from tracked masks
    assert _settings(needy).masks.tracking == "classical"
    with pytest.raises(ConfigError, match="learns from tracked masks"):
        _settings(needy, **{"masks.tracking": "none"})


def test_the_stage_runs_only_where_tracking_is_on():
    from benchmark.cache import PlanCache
    from benchmark.methods import get_method
    from benchmark.pipeline import tracks
    from benchmark.pipeline.context import SequenceRun

    def records(settings):
        scene = types.SimpleNamespace(train=[], test=[], truth=object())
        ctx = SequenceRun(PlanCache(Path("/nonexistent-trase-bench-cache")), scene, settings, get_method("trase"),
                          False, scene_key="scene", gt_key="gt")
        ctx.records["masks"] = types.SimpleNamespace(key="m")
        ctx.records["geometry"] = types.SimpleNamespace(key="g")
        return tracks.run(ctx)

    assert records(_settings()) == []
    syn, cla = records(_settings(**{"masks.tracking": "synthetic"})), records(_settings(**{"masks.tracking": "classical"}))
    assert len(syn) == len(cla) == 1 and syn[0].key != cla[0].key and syn[0].stage == "tracks"


@pytest.mark.slow
def test_a_run_with_synthetic_tracking_is_labelled_tracked_from_ground_truth(tmp_path, capsys):
    from benchmark.cli import main
    from benchmark.datasets.synthetic import generate
    from benchmark.results.runs import protocol, protocol_label

    generate("hypernerf", tmp_path / "hypernerf" / "synthetic", seed=0, size="tiny")
    out = tmp_path / "runs"
    args = ["run", "--method", "trase", "--dataset", "hypernerf", "--sequence", "synthetic", "--data-root",
            str(tmp_path), "--runs", str(out), "--quiet", "--set", "geometry.source=ground-truth",
            "--set", "method.features.iterations=20", "--set", "method.features.n_pixels=200",
            "--set", "masks.tracking=synthetic"]
    assert main(args) == 0
    (path,) = out.glob("trase/hypernerf/synthetic/*/results.json")
    rec = json.loads(path.read_text())
    assert rec["config"]["masks"]["tracking"] == "synthetic"
    assert rec["stages"]["tracks"]["info"]["source"] == "synthetic-truth"
    label = protocol_label(protocol(rec))
    assert "tracks tracked from ground truth (synthetic instance maps)" in label
    capsys.readouterr()
    assert main(["runs", "--runs", str(out)]) == 0
    assert "tracked from ground truth" in capsys.readouterr().out


def test_a_method_that_needs_tracks_reads_them_from_its_masks_dir(tiny_scene, tmp_path):
    """The stages as a run chains them, with a method whose learn reads the tracked masks."""
    import masks as masklib
    from benchmark.cache import StageCache
    from benchmark.methods.trase_method import TraseMethod
    from benchmark.pipeline import fit, geometry, masks, tracks
    from benchmark.pipeline.context import SequenceRun, scene_fingerprint

    seen = {}

    class Needy(TraseMethod):
        needs_tracks = True

        def learn(self, scene, gaussians, deformation, masks_dir, config, work_dir, progress=False):
            seen["info"] = load_tracks_info(masks_dir)
            seen["ids"] = [load_ids(ids_path(masks_dir, v.name)) for v in scene.train]
            seen["masks"] = [masklib.load(masklib.mask_path(masks_dir, v.name)).n for v in scene.train]
            return np.zeros((gaussians.num_gaussians, 2), np.float32), {}

    method = Needy()
    method.name = "needy"
    settings = _settings(method, **{"geometry.source": "ground-truth"})
    assert settings.masks.tracking == "classical"
    ctx = SequenceRun(StageCache(tmp_path / "cache"), tiny_scene, settings, method, False,
                      scene_fingerprint(tiny_scene), "gt")
    for stage in (masks.run, geometry.run, tracks.run):
        for rec in stage(ctx):
            ctx.records[rec.stage] = rec
    feats = fit._features(ctx)
    assert seen["info"]["source"] == "classical" and seen["info"]["n_tracks"] == max(int(i.max()) for i in seen["ids"])
    assert all(n > 0 for n in seen["masks"])
    assert feats.key == fit._features(ctx).key  # keyed by the tracks too, and cached
    untracked = _settings(**{"geometry.source": "ground-truth"})
    assert tracks.run(SequenceRun(StageCache(tmp_path / "cache"), tiny_scene, untracked, method, False,
                                  scene_fingerprint(tiny_scene), "gt")) == []
