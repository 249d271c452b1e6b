"""RunSettings: one preset key (and its old spelling), resolved and typed once, cache keys of
resolved values, the run's group over seeds."""

import pytest

from benchmark.cache import config_hash
from benchmark.config import ConfigError, parse_overrides
from benchmark.datasets.registry import get_dataset
from benchmark.methods import get_method
from benchmark.methods.trase_presets import TraseSettings
from benchmark.pipeline.settings import key_config, run_settings
from trase.reconstruction_config import ReconstructionConfig


def _settings(*sets, dataset="hypernerf", size=(160, 120)):
    return run_settings(get_method("trase"), get_dataset(dataset), "synthetic", parse_overrides(list(sets)), size)


def test_one_preset_key_and_its_old_spelling_with_a_notice(capsys):
    new = _settings("preset=cpu-v2")
    assert capsys.readouterr().err == ""
    old = _settings("geometry.preset=cpu-v2")
    assert "--set geometry.preset is now --set preset" in capsys.readouterr().err
    assert new.to_dict() == old.to_dict() and new.preset == "cpu-v2" and new.geometry.preset == "cpu-v2"
    assert _settings("preset=cpu", "geometry.preset=cpu").preset == "cpu"  # the same twice: fine
    with pytest.raises(ConfigError, match=r"^--set preset=paper and --set geometry.preset=cpu disagree: give one"):
        _settings("preset=paper", "geometry.preset=cpu")


def test_typed_once_with_the_methods_settings_class():
    s = _settings("method.features.iterations=5")
    assert isinstance(s.geometry.train, ReconstructionConfig) and isinstance(s.method, TraseSettings)
    assert s.method.features.iterations == 5 and s.sources["method.features.iterations"] == "--set"
    assert s.method.clustering.params["min_cluster_size"] == 50 and s.geometry.train.device == "cpu"
    with pytest.raises(ConfigError, match=r'--set method.clustering.min_sample="all": expected a whole number'):
        _settings('method.clustering.min_sample="all"')
    with pytest.raises(ConfigError, match="method.prompts: is a section"):
        _settings("method.prompts=3")


def test_the_geometry_key_hashes_resolved_values_not_the_presets_name():
    # on a multi-view rig cpu-v3 trains exactly as cpu-v2: one geometry, two protocol labels
    v2, v3 = _settings("preset=cpu-v2", dataset="neu3d"), _settings("preset=cpu-v3", dataset="neu3d")
    assert key_config(v2.geometry) == key_config(v3.geometry)
    assert config_hash(v2.to_dict()) != config_hash(v3.to_dict())  # the runs stay apart
    mono2, mono3 = _settings("preset=cpu-v2"), _settings("preset=cpu-v3")
    assert key_config(mono2.geometry) != key_config(mono3.geometry)  # a monocular rig: they differ


def test_the_group_leaves_the_run_seed_out_and_is_default_means_no_setting_changed():
    s0, s3 = _settings(), _settings("seed=3")
    assert s3.seed == 3 and s3.method.features.seed == s3.geometry.train.seed == 3
    assert s0.group_hash == s3.group_hash and s0.is_default and s3.is_default
    assert config_hash(s0.to_dict()) == s0.group_hash  # seed 0, nothing set: the run is its group
    assert _settings("preset=cpu").is_default and _settings("geometry.train.device=cpu").is_default
    changed = _settings("seed=3", "method.features.iterations=5")
    assert not changed.is_default and changed.group_hash != s0.group_hash
    pinned = _settings("seed=3", "method.features.seed=7")  # an explicit section seed stays in the group
    assert pinned.method.features.seed == 7 and pinned.group_hash != s0.group_hash
    assert not _settings("preset=paper").is_default


def test_a_run_resolves_its_settings_once_per_sequence(monkeypatch, tmp_path):
    from benchmark import runner

    calls = []
    real = runner.run_settings
    monkeypatch.setattr(runner, "run_settings", lambda *a, **k: calls.append(1) or real(*a, **k))
    opts = runner.RunOptions(method="trase", dataset="hypernerf", data_root=tmp_path, out_dir=tmp_path / "runs",
                             overrides=["seed=2"])
    from benchmark.datasets.synthetic import generate

    generate("hypernerf", tmp_path / "hypernerf" / "synthetic", seed=0, size="tiny")
    p = runner.prepare_sequence(opts, "synthetic")
    assert calls == [1]
    assert p.name == f"c{p.settings.group_hash[:8]}-s2" and p.group == _settings(size=(64, 48)).group_hash
    assert p.settings.method.unseen_min_weight == 0.5  # the tiny scene's images: the cpu preset's rule


def test_stopping_settings_are_recorded_and_keyed_only_where_stopping_is_on():
    # the cpu preset stops the feature stage (not the reconstruction)
    assert _settings().method.features.stop_interval == 250 and _settings().geometry.train.stop_interval == 0
    off, on = _settings("method.features.stop_interval=0"), _settings("geometry.train.stop_interval=500")
    rec = off.to_dict()
    assert not any(k.startswith("stop_") for k in rec["geometry"]["train"]) and "stop_patience" not in rec["method"]["features"]
    assert not any(k.startswith("stop_") for k in key_config(off.geometry)["train"])
    on_rec = on.to_dict()
    assert on_rec["method"]["features"]["stop_patience"] == 2 and on_rec["geometry"]["train"]["stop_interval"] == 500
    assert key_config(on.geometry) != key_config(off.geometry) and on.group_hash != off.group_hash
    # features-only stopping shares the geometry stage with the run without it
    feats_only = _settings()
    assert key_config(feats_only.geometry) == key_config(off.geometry)


def test_settings_at_their_as_before_value_are_neither_recorded_nor_keyed():
    """Static gaussians off (static_threshold 0) and the cpu presets' scale rule ("clamp") do what
    the code did before those settings existed: left out of the record, the hash and the
    geometry stage's key, with the static_* settings that act only through the threshold."""
    from benchmark.pipeline.settings import AS_BEFORE

    assert set(AS_BEFORE) >= {"stop_interval", "static_threshold", "deform_scale_rule"}
    base = _settings()
    assert base.geometry.train.static_threshold == 0.0 and base.geometry.train.deform_scale_rule == "clamp"
    rec, key = base.to_dict()["geometry"]["train"], key_config(base.geometry)["train"]
    for d in (rec, key):
        assert not any(k.startswith("static_") for k in d) and "deform_scale_rule" not in d
    # a static_from of its own changes nothing while the threshold is 0 ...
    assert _settings("geometry.train.static_from=2000").group_hash == base.group_hash
    # ... and everything once it is on; so does another scale rule
    on = _settings("geometry.train.static_threshold=0.01")
    assert on.to_dict()["geometry"]["train"]["static_from"] == base.geometry.train.static_from
    assert key_config(on.geometry) != key_config(base.geometry) and on.group_hash != base.group_hash
    mirror = _settings("geometry.train.deform_scale_rule=mirror")
    assert mirror.to_dict()["geometry"]["train"]["deform_scale_rule"] == "mirror"
    assert key_config(mirror.geometry) != key_config(base.geometry)
    assert _settings("preset=paper").to_dict()["geometry"]["train"]["deform_scale_rule"] == "mirror"
    # with the threshold on, static_from is keyed again
    assert _settings("geometry.train.static_threshold=0.01", "geometry.train.static_from=2000").group_hash != on.group_hash
    # the hold region, added later: at 0 (hold everything, as before) neither recorded nor keyed
    assert "static_hold_error" not in on.to_dict()["geometry"]["train"] and "static_time_gap" in key_config(on.geometry)["train"]
    gap = _settings("geometry.train.static_threshold=0.01", "geometry.train.static_time_gap=5")
    held = _settings("geometry.train.static_threshold=0.01", "geometry.train.static_time_gap=5",
                     "geometry.train.static_hold_error=0.2")
    assert "static_hold_error" not in gap.to_dict()["geometry"]["train"]
    assert held.to_dict()["geometry"]["train"]["static_hold_error"] == 0.2 and held.group_hash != gap.group_hash
    # only the settings named beside a switch go, never a look-alike of another section
    from benchmark.pipeline.settings import recorded_settings

    other = {"stop_interval": 0, "stop_patience": 2, "stop_after_s": 5, "static_threshold": 0.0, "static_scene": "y"}
    assert recorded_settings({"x": other}) == {"x": {"stop_after_s": 5, "static_scene": "y"}}


def test_the_numeric_mode_is_recorded_and_native_runs_keep_their_names():
    spec, method = get_dataset("hypernerf"), get_method("trase")
    portable = run_settings(method, spec, "synthetic", {}, (160, 120))
    native = run_settings(method, spec, "synthetic", parse_overrides(["machine.numerics=native"]), (160, 120))
    assert portable.to_dict()["machine"] == {"numerics": "portable"} and portable.is_default
    # native numerics are what the code computed before the modes: the record and hash of then
    assert "machine" not in native.to_dict() and not native.is_default
    assert config_hash(native.to_dict()) == config_hash({k: v for k, v in portable.to_dict().items() if k != "machine"})
    assert native.group_hash != portable.group_hash
    with pytest.raises(ConfigError, match="machine.numerics=fast: choose portable or native"):
        run_settings(method, spec, "synthetic", parse_overrides(["machine.numerics=fast"]), (160, 120))


def test_a_scheduled_geometry_key_names_the_schedules_code_version_and_the_others_stay():
    """A change to the resolution schedule's code must not reuse its older results, and must not
    throw away every other reconstruction's cache with them."""
    from types import SimpleNamespace

    from benchmark.pipeline.geometry import geometry_key_inputs
    from trase.resolution_schedule import SCHEDULE_VERSION

    off = SimpleNamespace(scene_key="abc", settings=_settings())
    on = SimpleNamespace(scene_key="abc", settings=_settings("geometry.train.resolution_schedule=frequency"))
    assert geometry_key_inputs(off) == {"scene": "abc"}  # the keys of before
    assert geometry_key_inputs(on) == {"scene": "abc", "resolution_schedule_version": str(SCHEDULE_VERSION)}


def test_a_set_objective_reads_the_presets_declarations_for_it():
    """TRASE's rule for its own objective (the soft correspondence on small monocular images)
    does not follow a run that trains another objective through --set."""
    own = _settings(size=(64, 48))
    assert own.method.features.objective_params == {"correspondence": "jaccard"}
    other = _settings("method.features.objective=trase-all", size=(64, 48))
    assert other.method.features.objective == "trase-all" and other.method.features.objective_params == {}


def test_the_frequency_schedules_settings_are_recorded_while_either_schedule_reads_them():
    """resolution_max_factor and resolution_until act through either schedule: left out only
    while both are off (as before the schedules), recorded and keyed once either is on."""
    base = _settings().to_dict()["geometry"]["train"]
    assert not {"resolution_schedule", "primitive_schedule", "resolution_max_factor", "resolution_until"} & set(base)
    assert _settings("geometry.train.resolution_until=500").group_hash == _settings().group_hash
    for on in (["geometry.train.primitive_schedule=frequency"], ["geometry.train.resolution_schedule=frequency"]):
        rec = _settings(*on).to_dict()["geometry"]["train"]
        assert {"resolution_max_factor", "resolution_until"} <= set(rec)
        assert _settings(*on, "geometry.train.resolution_until=500").group_hash != _settings(*on).group_hash
    resolution_only = _settings("geometry.train.resolution_schedule=frequency").to_dict()["geometry"]["train"]
    assert "primitive_schedule" not in resolution_only
