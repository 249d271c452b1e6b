"""gaussian-grouping through `trase-bench run` on the tiny synthetic HyperNeRF-format scene,
with ground-truth geometry and track ids from the scene's instance maps (`masks.tracking=synthetic`,
the tracks stage), 150 steps: the run completes and is recorded with its tracks' protocol."""

import json
import time
from importlib.metadata import version

import pytest

pytest.importorskip("trase_bench_grouping")


@pytest.mark.slow
def test_gaussian_grouping_runs_the_tiny_scene(tmp_path, monkeypatch):
    from benchmark.cli import main
    from benchmark.results.runs import protocol

    t0 = time.perf_counter()
    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path / "cache"))
    runs = tmp_path / "runs"
    rc = main(["run", "--method", "gaussian-grouping", "--dataset", "hypernerf", "--sequence", "synthetic-tiny",
               "--runs", str(runs), "--set", "geometry.source=ground-truth", "--set", "preset=cpu",
               "--set", "method.features.iterations=150", "--set", "masks.tracking=synthetic", "--quiet"])
    assert rc == 0
    (path,) = runs.glob("gaussian-grouping/hypernerf/synthetic-tiny/*/results.json")
    record = json.loads(path.read_text())
    assert record["versions"]["trase-bench-grouping"] == version("trase-bench-grouping")  # the installed one
    assert record["config"]["method"]["features"]["dim"] == 16
    assert 0.0 <= record["metrics"]["official"]["miou"] <= 1.0 and record["oracle"] is not None
    assert record["click_clusters"] and all(k != 0 for k in record["click_clusters"])
    assert (path.parent / "pred" / "00000.png").is_file()
    assert "ground truth" in protocol(record)["tracks"]  # tracked ids from the truth: a protocol of its own
    print(f"gaussian-grouping tiny run: mIoU {record['metrics']['official']['miou']:.4f}, "
          f"oracle {record['oracle']['miou']:.4f} in {time.perf_counter() - t0:.1f} s")
