"""A stage gives the same bits whatever ran before it in its process: the features trained right
after the reconstruction, in the process that reconstructed, equal those trained in a fresh
process that read the reconstruction from the cache (and so the run's results)."""

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from benchmark.cli import main

ROOT = Path(__file__).resolve().parents[2]
SETS = ["geometry.train.iterations=60", "method.features.iterations=60", "method.features.n_pixels=400"]
AFTER_GEOMETRY = ("features", "fit", "prompts", "evaluate", "ceiling")


def _digest(stage_dir: Path) -> str:
    """The stage's outputs, byte for byte, but the seconds they took (its record; the fit's
    timings)."""
    h = hashlib.sha256()
    for p in sorted(stage_dir.rglob("*")):
        if p.is_file() and p.name != "_stage.json":
            data = p.read_bytes()
            if p.name == "fitted.json":
                data = json.dumps({k: v for k, v in json.loads(data).items() if k != "timings"}).encode()
            h.update(p.relative_to(stage_dir).as_posix().encode() + data)
    return h.hexdigest()


def _run(data: Path, runs: Path, cache: Path, fresh_process: bool) -> dict:
    args = ["run", "--method", "trase", "--dataset", "nerfds", "--sequence", "synthetic", "--data-root", str(data),
            "--runs", str(runs), "--cache", str(cache), "--quiet", "--set", "seed=1"]
    for s in SETS:
        args += ["--set", s]
    if fresh_process:
        subprocess.run([sys.executable, "-m", "benchmark.cli", *args], cwd=ROOT, check=True, capture_output=True,
                       timeout=600)
    else:
        assert main(args) == 0
    (path,) = runs.glob("trase/nerfds/synthetic/*/results.json")
    return json.loads(path.read_text())


@pytest.mark.slow
def test_features_computed_after_the_reconstruction_equal_those_after_the_cache(tmp_path):
    from benchmark.datasets.synthetic import generate

    data = tmp_path / "data"
    generate("nerfds", data / "nerfds" / "synthetic", seed=0, size="tiny")
    cache = tmp_path / "cache"
    computed = _run(data, tmp_path / "computed", cache, fresh_process=False)  # geometry, then features, one process
    assert not computed["stages"]["geometry"]["skipped"]
    digests = {s: _digest(cache / s / computed["stages"][s]["key"]) for s in AFTER_GEOMETRY}
    for s in AFTER_GEOMETRY:
        shutil.rmtree(cache / s)
    cached = _run(data, tmp_path / "cached", cache, fresh_process=True)  # geometry read from the cache
    assert cached["stages"]["geometry"]["skipped"] and not cached["stages"]["features"]["skipped"]
    assert {s: cached["stages"][s]["key"] for s in AFTER_GEOMETRY} == {s: computed["stages"][s]["key"]
                                                                      for s in AFTER_GEOMETRY}
    assert {s: _digest(cache / s / cached["stages"][s]["key"]) for s in AFTER_GEOMETRY} == digests
    assert cached["checksums"]["pred"] == computed["checksums"]["pred"]
    assert cached["metrics"] == computed["metrics"]
