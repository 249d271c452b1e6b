import json

import pytest

from benchmark.cache import STAGE_VERSIONS, StageCache, config_hash
from benchmark.errors import UserError
from benchmark.io import atomic_directory, atomic_write_json, read_json


def test_stage_runs_once_then_is_skipped(tmp_path):
    cache = StageCache(tmp_path)
    calls = []

    def work(d):
        calls.append(d)
        (d / "out.txt").write_text("x")
        return {"n": 1}

    key = cache.key("masks", {"gen": "synthetic"}, {"scene": "abc"})
    first = cache.run("masks", key, work)
    second = cache.run("masks", key, work)
    assert len(calls) == 1
    assert not first.skipped and second.skipped
    assert second.info == {"n": 1}
    assert (first.path / "out.txt").read_text() == "x"
    assert not first.path.with_name(key + ".partial").exists()


def test_keys_change_with_config_and_inputs(tmp_path):
    cache = StageCache(tmp_path)
    k = cache.key("features", {"dim": 32}, {"recon": "a"})
    assert k == cache.key("features", {"dim": 32}, {"recon": "a"})
    assert k != cache.key("features", {"dim": 16}, {"recon": "a"})
    assert k != cache.key("features", {"dim": 32}, {"recon": "b"})
    assert config_hash({"a": 1, "b": 2}) == config_hash({"b": 2, "a": 1})


def test_failed_stage_is_never_done_and_partial_resumes(tmp_path):
    cache = StageCache(tmp_path)
    key = cache.key("recon", {}, {})

    def crash(d):
        (d / "ckpt_1").write_text("1")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError):
        cache.run("recon", key, crash)
    assert not cache.is_done("recon", key)

    def resume(d):
        assert (d / "ckpt_1").exists()  # the checkpoint survived the crash
        (d / "model").write_text("m")

    rec = cache.run("recon", key, resume)
    assert cache.is_done("recon", key) and (rec.path / "model").exists()


def test_atomic_directory_leaves_nothing_on_failure(tmp_path):
    with pytest.raises(ValueError), atomic_directory(tmp_path / "d") as d:
        (d / "f").write_text("half")
        raise ValueError
    assert list(tmp_path.iterdir()) == []
    with atomic_directory(tmp_path / "d") as d:
        (d / "f").write_text("whole")
    assert (tmp_path / "d" / "f").read_text() == "whole"


def test_read_json_errors_name_the_file(tmp_path):
    p = tmp_path / "r.json"
    with pytest.raises(UserError, match="r.json: results not found"):
        read_json(p, "results")
    p.write_bytes(b"\xff\xfe{")
    with pytest.raises(UserError, match="r.json: results is not UTF-8"):
        read_json(p, "results")
    p.write_text('{"a": ')
    with pytest.raises(UserError, match="r.json: malformed JSON in results"):
        read_json(p, "results")
    atomic_write_json(p, {"a": 1})
    assert json.loads(p.read_text()) == {"a": 1}



def test_code_version_bump_gives_a_new_key(tmp_path, monkeypatch):
    import benchmark.cache as cache_mod

    cache = StageCache(tmp_path, numerics="native")  # native keys: as before the numeric modes
    cfg, inputs = {"knn": 0}, {"masks": "m"}
    monkeypatch.setattr(cache_mod, "STAGE_VERSIONS", {})
    v1 = cache.key("features", cfg, inputs)
    assert v1 == config_hash({"stage": "features", "config": cfg, "inputs": inputs})  # version 1: key unchanged
    monkeypatch.setattr(cache_mod, "STAGE_VERSIONS", {"features": 2})
    v2 = cache.key("features", cfg, inputs)
    assert v2 != v1
    assert cache.key("masks", cfg, inputs) == config_hash({"stage": "masks", "config": cfg, "inputs": inputs})


def test_stages_of_another_numeric_mode_have_other_keys(tmp_path):
    cfg, inputs = {"knn": 0}, {"masks": "m"}
    native = StageCache(tmp_path, numerics="native").key("features", cfg, inputs)
    portable = StageCache(tmp_path, numerics="portable").key("features", cfg, inputs)
    assert native != portable
    assert StageCache(tmp_path).key("features", cfg, inputs) == portable  # the default mode


def test_portable_stages_of_another_pinning_have_other_keys(tmp_path, monkeypatch):
    from benchmark import numerics

    cfg, inputs = {"knn": 0}, {"masks": "m"}
    now = StageCache(tmp_path, numerics="portable").key("features", cfg, inputs)
    monkeypatch.setattr(numerics, "PINNING", 1)
    first = StageCache(tmp_path, numerics="portable").key("features", cfg, inputs)
    assert first == config_hash({"stage": "features", "config": cfg, "inputs": inputs, "numerics": "portable",
                                 "code_version": STAGE_VERSIONS["features"]})  # the keys of the first pinning
    assert now != first
