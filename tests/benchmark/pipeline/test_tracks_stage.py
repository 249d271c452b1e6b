"""The tracks stage (benchmark.pipeline.tracks): ids from the synthetic truth, from a tracker's
files (DEVA's layout); the warp the classical tracker uses; the masks.tracking setting and the
protocol. The tracker itself: test_classical_tracker.py."""

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
from masks.tracked import TrackFileError, ids_path, load_ids, load_tracks_info


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
