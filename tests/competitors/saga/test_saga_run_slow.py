"""``trase-bench run --method saga`` end to end on the tiny synthetic scene with ground-truth
geometry: the entry point resolves, every stage runs, the run records the plugin's version and
the oracle beside the score."""

import json

import pytest

from benchmark.cli import main

pytestmark = pytest.mark.slow


def test_saga_runs_on_the_tiny_scene(tmp_path):
    runs = tmp_path / "runs"
    rc = main(["run", "--method", "saga", "--dataset", "hypernerf", "--sequence", "synthetic-tiny",
               "--runs", str(runs), "--quiet", "--set", "preset=cpu", "--set", "geometry.source=ground-truth",
               "--set", "method.features.iterations=60"])
    assert rc == 0
    (path,) = list(runs.glob("saga/hypernerf/synthetic-tiny/*/results.json"))
    r = json.loads(path.read_text())
    assert r["method"] == "saga"
    assert "trase-bench-saga" in json.dumps(r["versions"])
    assert 0.0 <= r["metrics"]["miou"] <= 1.0 and 0.0 <= r["oracle"]["miou"] <= 1.0
    assert r["ceiling"]["miou"] > 0.5
    assert r["stages"]["features"]["info"]["saga"]["gate"]["weight"]
    assert r["config"]["method"]["inference"]["threshold"] == 0.65  # the cpu preset
