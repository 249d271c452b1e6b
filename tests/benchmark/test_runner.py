"""End-to-end: the whole pipeline on a tiny synthetic scene, results file, cache reuse, leaderboard."""

import json

import pytest

from benchmark.cli import main
from benchmark.config import ConfigError, merge, parse_overrides
from benchmark.datasets.synthetic import generate
from benchmark.results import load_results

FAST = [
    "geometry.source=ground-truth",
    "method.features.iterations=40",
    "method.features.n_pixels=400",
]


@pytest.fixture(scope="module")
def data_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    generate("hypernerf", root / "hypernerf" / "synthetic", seed=0, size="tiny")
    return root


def _run(data_root, out, method="trase", extra=(), name=None):
    args = ["run", "--method", method, "--dataset", "hypernerf", "--sequence", "synthetic",
            "--data-root", str(data_root), "--runs", str(out), "--quiet"] + (["--name", name] if name else [])
    for s in FAST + list(extra):
        args += ["--set", s]
    return main(args)


def _runs(out, method="trase"):
    """The run directories of ``method`` on the tiny scene, oldest first."""
    return sorted((p.parent for p in (out / method / "hypernerf" / "synthetic").glob("*/results.json")),
                  key=lambda d: (d / "results.json").stat().st_mtime_ns)


@pytest.mark.slow
def test_pipeline_end_to_end(data_root, tmp_path, capsys):
    out = tmp_path / "runs"
    assert _run(data_root, out) == 0
    (run_dir,) = _runs(out)
    path = run_dir / "results.json"
    r = load_results(path)
    assert r["run"]["kind"] == "run" and r["run"]["overrides"] == FAST  # made with --set: not a main run
    assert run_dir.name == r["run"]["name"] == "c" + r["config_hash"][:8]
    assert r["metrics"]["official"]["metric_version"] == "official/script1"
    assert r["storage"]["total_mib"] > 0 and r["storage"]["features_bytes"] == r["n_gaussians"] * 32 * 4
    assert r["variant"] == "synthetic"
    assert r["metrics"]["metric_version"] == "v1/bin2"
    assert 0.0 <= r["metrics"]["miou"] <= 1.0
    assert r["metrics"]["n_frames"] == len(r["per_frame"]) == len(r["frames"]) > 0
    assert set(r["stages"]) == {"masks", "geometry", "features", "fit", "prompts", "evaluate", "ceiling"}
    assert not any(s["skipped"] for s in r["stages"].values())
    assert r["config"]["method"]["features"]["iterations"] == 40
    assert r["seeds"]["features"] == 0 and len(r["checksums"]["pred"]) == 16
    assert r["prompts"]["clicks"] and r["prompts"]["source"] == "gt-first-appearance"
    # the corrective protocol: its curve starts at the first clicks, its clicks in the run's prompts.json
    c = r["corrective"]
    assert c["curve"][0]["clicks"] == c["first_clicks"] == len(r["prompts"]["clicks"]) and c["negatives"] is True
    assert len(c["curve"]) == 1 + len(c["corrections"]) + len(c["undone"]) <= 1 + c["budget"]
    assert c["first_clicks"] <= c["noc@85"] <= c["noc@90"] <= c["first_clicks"] + c["budget"] + 1
    assert r["metrics"]["official"]["miou"] == c["curve"][-1]["miou"]
    saved = json.loads((path.parent / "prompts.json").read_text())
    assert saved["clicks"] == r["prompts"]["clicks"] and saved["corrections"] == c["corrections"]
    assert (path.parent / "pred" / "00000.png").exists()
    # synthetic scene: the geometry's ceiling (truth-labelled gaussians) is reported beside the score;
    # with the ground-truth geometry it is near perfect
    assert r["ceiling"]["rule"] == r["config"]["method"]["render_rule"]
    assert r["ceiling"]["n_selected"] > 0 and r["ceiling"]["miou"] > 0.85
    assert 0 <= r["ceiling"]["object_alpha"]["holes"] <= 1 and r["ceiling"]["object_alpha"]["gt_pixels"] > 0
    assert r["ceiling"]["training_views"]["n_views"] > 0 and r["ceiling"]["training_views"]["miou"] > 0.85
    # which synthetic scene (standard or hard) the figure was measured on
    assert r["synthetic_scene"]["difficulty"] in ("standard", "hard") and r["synthetic_scene"]["generator_version"]

    # a second method on the same scene reuses masks and geometry
    assert _run(data_root, out, method="trase-hard") == 0
    r2 = load_results(_runs(out, "trase-hard")[0] / "results.json")
    assert r2["stages"]["masks"]["skipped"] and r2["stages"]["geometry"]["skipped"]
    assert not r2["stages"]["features"]["skipped"] and not r2["stages"]["fit"]["skipped"]
    assert r2["stages"]["masks"]["key"] == r["stages"]["masks"]["key"]
    # the geometry's ceiling is computed once per geometry and rule, then reused
    assert r2["ceiling"]["miou"] == r["ceiling"]["miou"]
    assert len(list((out / ".cache" / "ceiling").iterdir())) == 1

    # a rerun reuses everything and gives identical metrics (determinism)
    assert _run(data_root, out) == 0
    r3 = load_results(path)
    assert all(s["skipped"] for s in r3["stages"].values())  # evaluation is a cached stage too
    assert r3["metrics"] == r["metrics"] and r3["checksums"] == r["checksums"]

    # a clustering change reuses the trained features and reruns only the fit stage, in a run
    # directory of its own: the first result is still there, unchanged
    assert _run(data_root, out, extra=["method.clustering.fraction=0.5"]) == 0
    first, other = _runs(out)
    assert first == run_dir and load_results(path)["metrics"] == r["metrics"]
    r4 = load_results(other / "results.json")
    assert r4["stages"]["features"]["skipped"] and not r4["stages"]["fit"]["skipped"]
    # a named run is never overwritten by another config
    assert _run(data_root, out, name="mine") == 0
    capsys.readouterr()
    assert _run(data_root, out, extra=["method.clustering.fraction=0.5"], name="mine") == 1
    assert "a run with another config exists" in capsys.readouterr().err

    # main runs only by default: none here (every run used --set); the other kinds when asked
    assert main(["leaderboard", "--runs", str(out), "--variant", "synthetic"]) == 0
    assert "HyperNeRF-Mask" not in capsys.readouterr().out
    assert main(["leaderboard", "--runs", str(out), "--variant", "synthetic", "--kind", "run"]) == 1
    assert "runs with different configs" in capsys.readouterr().err  # fraction 0.5 beside the first
    assert main(["leaderboard", "--run", str(run_dir), "--run", str(_runs(out, "trase-hard")[0]),
                 "--variant", "synthetic"]) == 0
    board = capsys.readouterr().out
    assert "HyperNeRF-Mask" in board and "trase-hard [a]" in board and "(published)" not in board
    assert "[a] scene synthetic v" in board and " seed 0 " in board  # which synthetic scene
    assert main(["report", "--method", "trase", "--dataset", "hypernerf", "--sequence", "synthetic",
                 "--name", run_dir.name, "--runs", str(out)]) == 0
    assert (path.parent / "report.html").exists()


def test_unknown_setting_is_an_error(data_root, tmp_path, capsys):
    assert _run(data_root, tmp_path, extra=["method.features.itterations=5"]) == 1
    assert "unknown setting" in capsys.readouterr().err


def test_a_missing_data_root_is_an_error_and_an_empty_one_is_said(tmp_path, capsys, monkeypatch):
    from benchmark.datasets import get_dataset
    from benchmark.runner import default_sequences

    monkeypatch.delenv("TRASE_DATA", raising=False)
    args = ["run", "--method", "trase", "--dataset", "hypernerf", "--data-root", str(tmp_path / "nowhere"),
            "--runs", str(tmp_path / "runs"), "--quiet"]
    assert main(args) == 1
    assert "nowhere: no such directory (the data root given by --data-root)" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()
    assert default_sequences(get_dataset("hypernerf"), tmp_path) == [None]  # no sequence there: the synthetic one
    assert "note: no hypernerf sequence under" in capsys.readouterr().err
    assert default_sequences(get_dataset("hypernerf"), None) == [None]  # no root given: nothing to say
    assert capsys.readouterr().err == ""


def test_a_synthetic_scene_under_the_data_root_is_named_as_the_one_run(tmp_path, capsys):
    """`trase-bench synth --out ROOT/D/synthetic` writes a scene a run then takes in place of the
    built-in one: the note says so, with its path."""
    from benchmark.datasets import get_dataset
    from benchmark.runner import default_sequences

    scene = tmp_path / "hypernerf" / "synthetic"
    (scene / "synthetic").mkdir(parents=True)
    (scene / "synthetic" / "manifest.json").write_text("{}")
    assert default_sequences(get_dataset("hypernerf"), tmp_path) == [None]
    err = capsys.readouterr().err
    assert f"running the synthetic scene written there, {scene}" in err
    assert "built-in" not in err


def test_overrides_parse_and_merge():
    o = parse_overrides(["a.b=3", "a.c=true", "d=text", "e=[1, 2]"])
    assert o == {"a": {"b": 3, "c": True}, "d": "text", "e": [1, 2]}
    base = {"a": {"b": 1, "c": False}, "d": "x", "e": []}
    assert merge(base, o) == o
    with pytest.raises(ConfigError, match="a.z: unknown setting"):
        merge(base, {"a": {"z": 1}})
    with pytest.raises(ConfigError, match="expected key=value"):
        parse_overrides(["novalue"])
    with pytest.raises(ConfigError, match="is a section"):
        merge(base, {"a": 5})


def test_paper_preset_takes_the_registry_schedule():
    from benchmark.datasets import get_dataset
    from benchmark.methods import get_method
    from tests.benchmark.settings_helpers import resolved_dict

    spec = get_dataset("hypernerf")
    cfg = resolved_dict(get_method("trase"), spec, "real", {"preset": "paper"})
    train = cfg["geometry"]["train"]
    assert (train["warm_up"], train["densify_until"]) == (spec.warm_up, spec.densify_until) == (1500, 9000)
    # one click rule under every preset: the rendered feature's nearest cluster
    assert cfg["method"]["prompts"]["click_rule"] == "feature"
    assert resolved_dict(get_method("trase"), spec, "real", {"preset": "cpu"})["method"]["prompts"][
        "click_rule"] == "feature"
    assert train["iterations"] == 20_000 and train["image_downscale"] == 1.0
    # one preset for the whole run: the paper's geometry comes with the paper's method settings
    assert cfg["method"]["preset"] == "paper" and cfg["method"]["features"]["iterations"] == 10_000
    assert resolved_dict(get_method("trase"), spec, "real", {"preset": "cpu-v1"})["method"]["preset"] == "cpu"
    multi = get_dataset("technicolor")
    for preset, mono_its, multi_its, mono_prune in (("cpu", 4000, 4000, 0.1), ("cpu-v4", 4000, 2000, 0.1),
                                                    ("cpu-v3", 4000, 2000, 0.005),
                                                    ("cpu-v2", 2000, 2000, 0.005), ("cpu-v1", 2000, 2000, 0.005)):
        cfg = resolved_dict(get_method("trase"), spec, "real", {"preset": preset})
        assert cfg["geometry"]["train"]["iterations"] == mono_its and cfg["method"]["preset"] == "cpu"
        assert cfg["geometry"]["train"]["min_opacity"] == mono_prune
        cfg = resolved_dict(get_method("trase"), multi, "real", {"preset": preset})
        assert cfg["geometry"]["train"]["iterations"] == multi_its
        assert cfg["geometry"]["train"]["min_opacity"] == 0.005  # multi-view rigs: no change since cpu-v2
    with pytest.raises(ConfigError, match="method.preset=paper: the method's preset follows the run's"):
        resolved_dict(get_method("trase"), spec, "real", {"preset": "cpu", "method": {"preset": "paper"}})
    with pytest.raises(ConfigError, match="preset=gpu: choose auto, paper, cpu-v1, cpu-v2, cpu-v3, cpu-v4, cpu"):
        resolved_dict(get_method("trase"), spec, "real", {"preset": "gpu"})


def test_cpu_preset_training_resolution_follows_the_images():
    from benchmark.datasets import get_dataset
    from benchmark.methods import get_method
    from tests.benchmark.settings_helpers import resolved_dict
    from trase.reconstruction_presets import cpu_train_downscale

    assert cpu_train_downscale(None) == 1.0
    assert cpu_train_downscale((160, 120)) == 1.0  # synthetic scenes train at full resolution
    assert cpu_train_downscale((480, 270)) == 1.0
    assert cpu_train_downscale((960, 536)) == 2.0  # HyperNeRF
    assert cpu_train_downscale((1352, 1014)) == 4.0  # Neu3D
    spec = get_dataset("hypernerf")
    cfg = resolved_dict(get_method("trase"), spec, "synthetic", {"preset": "cpu"}, (160, 120))
    train = cfg["geometry"]["train"]
    assert train["image_downscale"] == 1.0 and train["iterations"] == 4000
    assert (train["position_lr_max_steps"], train["deform_lr_max_steps"]) == (20_000, 20_000)  # no annealing in 4000 steps
    cfg = resolved_dict(get_method("trase"), spec, "real", {"preset": "cpu"}, (960, 536))
    assert cfg["geometry"]["train"]["image_downscale"] == 2.0


def test_run_seed_reaches_every_seeded_section_and_explicit_settings_win():
    from benchmark.config import parse_seeds
    from benchmark.datasets import get_dataset
    from benchmark.methods import get_method
    from tests.benchmark.settings_helpers import resolved_dict

    spec, method = get_dataset("hypernerf"), get_method("trase")
    cfg = resolved_dict(method, spec, "synthetic", parse_overrides(["seed=3"]), (160, 120))
    assert cfg["seed"] == 3
    assert cfg["geometry"]["train"]["seed"] == cfg["method"]["features"]["seed"] == 3
    assert cfg["method"]["clustering"]["seed"] == 3 and cfg["masks"]["seed"] == 0  # masks: the input
    cfg = resolved_dict(method, spec, "synthetic", parse_overrides(["seed=3", "method.features.seed=7"]))
    assert cfg["method"]["features"]["seed"] == 7 and cfg["method"]["clustering"]["seed"] == 3
    for bad in ("seed=-1", "seed=1.5", 'seed="a"', "seed=true"):
        with pytest.raises(ConfigError, match="run seed"):
            resolved_dict(method, spec, "synthetic", parse_overrides([bad]))
    assert parse_seeds("3") == [0, 1, 2] and parse_seeds("0,4,7") == [0, 4, 7] and parse_seeds("5,") == [5]
    for bad in ("0", "-1", "a", "1,1", "1,-2"):
        with pytest.raises(ConfigError, match="--seeds"):
            parse_seeds(bad)


@pytest.mark.slow
def test_seeds_are_runs_side_by_side_and_one_leaderboard_row(data_root, tmp_path, capsys):
    out = tmp_path / "runs"
    args = ["run", "--method", "trase", "--dataset", "hypernerf", "--sequence", "synthetic", "--data-root",
            str(data_root), "--runs", str(out), "--quiet", "--seeds", "2"]
    for s in FAST:
        args += ["--set", s]
    assert main(args) == 0
    first, second = _runs(out)
    a, b = (load_results(d / "results.json") for d in (first, second))
    assert (a["run"]["seed"], b["run"]["seed"]) == (0, 1) and a["run"]["group"] == b["run"]["group"]
    assert first.name == "c" + a["run"]["group"][:8] and second.name == first.name + "-s1"
    assert a["config_hash"] != b["config_hash"] and b["seeds"]["features"] == b["seeds"]["clustering"] == 1
    assert a["stages"]["masks"]["key"] == b["stages"]["masks"]["key"]  # the input is shared
    assert a["stages"]["features"]["key"] != b["stages"]["features"]["key"]
    # click sets: set 0 is the run's own clicks and score; the others are scored beside it
    sets = a["click_sets"]
    assert sets["n"] == 5 == len(sets["sets"]) and a["stages"]["prompts"]["info"]["click_sets"] == 5
    assert sets["sets"][0]["miou"] == a["metrics"]["official"]["miou"]
    assert sets["sets"][0]["selected"] == a["selected_clusters"]
    assert sets["sets"][0]["click_clusters"] == a["click_clusters"]
    # one cluster per click in force: the first clicks and the robot user's kept ones
    assert len(a["click_clusters"]) == len(a["prompts"]["clicks"]) + len(a["corrective"]["corrections"])
    assert sets["worst"] <= sets["median"] <= sets["best"]
    # clustering agreement between the seeds: same (ground-truth) geometry, so per gaussian too
    assert a["geometry_checksum"] == b["geometry_checksum"]
    assert (first / "clusters" / "labels.npy").is_file() and list((first / "clusters").glob("ids_*.png"))
    out_text = capsys.readouterr().out
    assert "over seeds 0,1: mIoU " in out_text and "pixel ARI" in out_text and "gaussian ARI" in out_text
    assert main(["leaderboard", "--runs", str(out), "--variant", "synthetic", "--kind", "run"]) == 0
    board = capsys.readouterr().out
    assert "| seeds |" in board and " ± " in board and board.split("###")[1].count("| trase [a]") == 1
    assert main(["report", "--method", "trase", "--dataset", "hypernerf", "--sequence", "synthetic",
                 "--runs", str(out), "--name", first.name]) == 0
    page = (first / "report.html").read_text()
    assert "cluster per click" in page and "seeds 0,1: mIoU" in page and "gaussian ARI" in page
    clicked = {c["view_index"] for cs in [a["prompts"]["clicks"], *a["prompts"]["alternatives"]] for c in cs}
    assert page.count("<figcaption>frame ") == len(clicked) > 1  # one picture per clicked frame
    assert main(args + ["--set", "seed=1"]) == 1
    assert "either with --seeds or with --set seed" in capsys.readouterr().err


def test_every_stage_renders_with_the_geometrys_near_plane(data_root, tmp_path):
    """The scene's cameras carry the near plane the geometry is reconstructed with (the paper
    preset's 0.2, the cpu presets' 0.01), so features, prompts, evaluate and ceiling draw what
    training drew; at the default nothing changes (the scene's key included), elsewhere the key
    changes with it (stages rendered at another plane are not reused)."""
    from benchmark.pipeline.context import recorded_render_near, scene_fingerprint
    from benchmark.runner import RunOptions, prepare_sequence

    def prepared(*overrides):
        opts = RunOptions("trase", "hypernerf", ["synthetic"], data_root, tmp_path, overrides=list(overrides))
        return prepare_sequence(opts, "synthetic", create=False)

    cpu = prepared()
    assert {v.camera.near for v in cpu.scene.train + cpu.scene.test} == {0.01}
    paper = prepared("geometry.train.near_plane=0.2")
    assert {v.camera.near for v in paper.scene.train + paper.scene.test} == {0.2}
    assert scene_fingerprint(paper.scene) != scene_fingerprint(cpu.scene)
    truth = prepared("geometry.train.near_plane=0.2", "geometry.source=ground-truth")
    assert {v.camera.near for v in truth.scene.test} == {0.01}  # not trained: the cameras' default
    assert scene_fingerprint(truth.scene) == scene_fingerprint(cpu.scene)
    assert recorded_render_near(paper.settings.to_dict()) == 0.2
    assert recorded_render_near({}) == recorded_render_near(cpu.settings.to_dict()) == 0.01
