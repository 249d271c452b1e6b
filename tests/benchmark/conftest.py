"""Shared fixtures: a tiny synthetic scene written as a capture in each layout
(benchmark.captures.write), and a tiny finished run (render, edit, view)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from benchmark.captures.write import write_colmap_folder, write_nerfies_capture, write_transforms


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory):
    from benchmark.datasets import load_scene
    from benchmark.datasets.synthetic import generate

    d = generate("hypernerf", tmp_path_factory.mktemp("synthetic") / "scene", seed=0, size="tiny")
    return load_scene("hypernerf", d)


@pytest.fixture(scope="session")
def capture_dirs(tiny_scene, tmp_path_factory) -> dict[str, Path]:
    """Pristine captures of the tiny scene's 6 views; copy before changing one."""
    s = tiny_scene
    root = tmp_path_factory.mktemp("captures")
    views = s.train + s.test
    return {
        "nerfies": write_nerfies_capture(views[:4], s.points, s.point_colors, root / "nerfies", unlisted=views[4:]),
        "colmap": write_colmap_folder(views, s.points, s.point_colors, root / "colmap"),
        "transforms": write_transforms(s.train, s.points, s.point_colors, root / "transforms", test_views=s.test),
    }


@pytest.fixture
def capture_copy(capture_dirs, tmp_path):
    def copy(layout: str) -> Path:
        return Path(shutil.copytree(capture_dirs[layout], tmp_path / layout))

    return copy


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory) -> Path:
    """A finished `trase-bench run` on the tiny HyperNeRF-format scene (ground-truth geometry,
    40 feature steps): a run folder with its stage cache."""
    from benchmark.cli import main
    from benchmark.datasets.synthetic import generate

    root = tmp_path_factory.mktemp("tiny-run")
    generate("hypernerf", root / "hypernerf" / "synthetic", seed=0, size="tiny")
    out = root / "runs"
    args = ["run", "--method", "trase", "--dataset", "hypernerf", "--sequence", "synthetic", "--data-root",
            str(root), "--runs", str(out), "--quiet", "--set", "geometry.source=ground-truth",
            "--set", "method.features.iterations=40", "--set", "method.features.n_pixels=400"]
    assert main(args) == 0
    (results,) = out.glob("trase/hypernerf/synthetic/*/results.json")
    return results.parent


@pytest.fixture(scope="session")
def slurm(tmp_path_factory):
    """A running one-node SLURM (tests/benchmark/slurm_cluster.py) with ``SLURM_CONF`` set for
    this process and its children; skipped with the reason where it cannot start."""
    import os

    from tests.benchmark.slurm_cluster import SlurmCluster, why_not

    why = why_not()
    if why:
        pytest.skip(f"no test SLURM: {why}")
    cluster = SlurmCluster(tmp_path_factory.mktemp("slurm")).start()
    old = os.environ.get("SLURM_CONF")
    os.environ["SLURM_CONF"] = str(cluster.conf)
    try:
        yield cluster
    finally:
        cluster.stop()
        if old is None:
            os.environ.pop("SLURM_CONF", None)
        else:
            os.environ["SLURM_CONF"] = old
