"""The synthetic scenes' cache and generation workflow: where a scene is written, what a rerun
finds, what bad arguments and failed generations leave behind, and ``trase-bench synth``."""

from __future__ import annotations

import json

import pytest

from benchmark.datasets import DatasetError, load_scene
from benchmark.datasets.synthetic import (
    GENERATOR_VERSION,
    SyntheticError,
    ensure_synthetic,
    find_or_generate,
    generate,
)

SIZE = "tiny"
SEQ = "synthetic-tiny"


def test_generate_refuses_non_empty_dir_and_bad_args(tmp_path):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "file").write_text("")
    with pytest.raises(SyntheticError, match="not empty"):
        generate("hypernerf", tmp_path / "x", size=SIZE)
    with pytest.raises(SyntheticError, match="unknown dataset"):
        generate("kitti", tmp_path / "y", size=SIZE)
    with pytest.raises(SyntheticError, match="unknown size"):
        generate("hypernerf", tmp_path / "y", size="huge")



def test_ensure_synthetic_caches_atomically(tmp_path, capsys):
    p = ensure_synthetic("hypernerf", size=SIZE, cache_dir=tmp_path)
    assert p == tmp_path / "hypernerf" / f"v{GENERATOR_VERSION}" / SEQ
    assert "generating" in capsys.readouterr().err
    assert ensure_synthetic("hypernerf", size=SIZE, cache_dir=tmp_path) == p
    assert capsys.readouterr().err == ""  # second call: cached, no notice
    assert sorted(x.name for x in p.parent.iterdir()) == [SEQ]  # no temp dirs left behind



def test_ensure_synthetic_refuses_other_generator_version(tmp_path):
    stale = tmp_path / "hypernerf" / f"v{GENERATOR_VERSION}" / SEQ / "synthetic"
    stale.mkdir(parents=True)
    (stale / "manifest.json").write_text(json.dumps({"generator_version": "0"}))
    with pytest.raises(SyntheticError, match=r"manifest.json: scene from generator version 0.*delete"):
        ensure_synthetic("hypernerf", size=SIZE, cache_dir=tmp_path)



def test_ensure_synthetic_uses_trase_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path))
    p = ensure_synthetic("hypernerf", size=SIZE)
    assert p == tmp_path / "synthetic" / "hypernerf" / f"v{GENERATOR_VERSION}" / SEQ



def test_find_or_generate(tmp_path, monkeypatch):
    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("TRASE_DATA", raising=False)
    # a data root named but missing: an error, not the synthetic scene in its place
    with pytest.raises(DatasetError, match=r"data: no such directory \(the data root given by --data-root\)"):
        find_or_generate("hypernerf", "synthetic-tiny", tmp_path / "data")
    monkeypatch.setenv("TRASE_DATA", str(tmp_path / "elsewhere"))
    with pytest.raises(DatasetError, match=r"elsewhere: no such directory \(the data root given by \$TRASE_DATA\)"):
        find_or_generate("hypernerf", "synthetic-tiny", None)
    monkeypatch.delenv("TRASE_DATA")
    # no real data: the synthetic default
    (tmp_path / "data").mkdir()
    d, variant = find_or_generate("hypernerf", "synthetic-tiny", tmp_path / "data")
    assert variant == "synthetic" and d == tmp_path / "cache" / "synthetic" / "hypernerf" / f"v{GENERATOR_VERSION}" / SEQ
    # a named real sequence that is missing: error naming where it looked
    with pytest.raises(SyntheticError, match=r"americano.*data/hypernerf/americano"):
        find_or_generate("hypernerf", "americano", tmp_path / "data")
    # real data wins
    real = tmp_path / "data" / "hypernerf" / "americano"
    real.mkdir(parents=True)
    assert find_or_generate("hypernerf", "americano", tmp_path / "data") == (real, "real")
    monkeypatch.setenv("TRASE_DATA", str(tmp_path / "data"))
    assert find_or_generate("hypernerf", "americano", None) == (real, "real")



def test_cli_synth(tmp_path):
    from benchmark.cli import main

    out = tmp_path / "scene"
    assert main(["synth", "--dataset", "hypernerf", "--out", str(out), "--size", "tiny", "--seed", "3"]) == 0
    man = json.loads((out / "synthetic" / "manifest.json").read_text())
    assert man["seed"] == 3 and man["size"] == "tiny"
    assert main(["synth", "--dataset", "hypernerf", "--out", str(out), "--size", "tiny"]) == 1



def test_failed_generation_leaves_nothing(tmp_path, monkeypatch):
    import importlib

    gen = importlib.import_module("benchmark.datasets.synthetic.generate")  # the module, not the function

    def broken(*a, **k):
        raise RuntimeError("loader exploded")

    monkeypatch.setattr(gen, "_load", broken)
    with pytest.raises(RuntimeError, match="exploded"):
        generate("hypernerf", tmp_path / "new" / SEQ, size=SIZE)
    assert not (tmp_path / "new" / SEQ).exists()
    (tmp_path / "empty").mkdir()
    with pytest.raises(RuntimeError):
        generate("hypernerf", tmp_path / "empty", size=SIZE)
    assert (tmp_path / "empty").is_dir() and not any((tmp_path / "empty").iterdir())



def test_find_or_generate_the_hard_variant(tmp_path, monkeypatch):
    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("TRASE_DATA", raising=False)
    d, variant = find_or_generate("hypernerf", "synthetic-tiny-hard", None)
    assert variant == "synthetic" and d.name == "synthetic-tiny-hard"
    man = json.loads((d / "synthetic" / "manifest.json").read_text())
    assert man["difficulty"] == "hard" and man["motion_span"] == 1.0 and man["time_statistics"] is None
    assert load_scene("hypernerf", d).sequence == "synthetic-tiny-hard"
