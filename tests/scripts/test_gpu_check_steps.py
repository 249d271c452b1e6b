import importlib.util
import os
import tarfile
import types
from pathlib import Path

import pytest
import torch

SCRIPTS = Path(__file__).parents[2] / "scripts"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


steps = _load("gpu_check_steps")


class _Check:
    """The orchestrator's check, recording the commands it would run."""

    def __init__(self):
        self.ran = []

    def left(self):
        return 100.0

    def sh(self, name, cmd, timeout, env=None):
        self.ran.append((name, env))
        return {"rc": 0}

    def save(self):
        pass


def test_a_saved_build_is_unpacked_with_its_times_and_the_sources_dated_before_it(tmp_path, monkeypatch):
    """The reuse path of a gsplat build: the archive's files come back with their own times, and
    every file of the gsplat package is dated back so that ninja finds each object newer than its
    inputs; the build step then runs with TORCH_EXTENSIONS_DIR at the unpacked folder."""
    built = tmp_path / "built" / "gsplat_cuda"
    built.mkdir(parents=True)
    (built / "gsplat_cuda.so").write_bytes(b"so")
    os.utime(built / "gsplat_cuda.so", (1.9e9, 1.9e9))
    archive = tmp_path / "build.tar.gz"
    with tarfile.open(archive, "w:gz") as tar:
        tar.add(tmp_path / "built", arcname=".")
    package = tmp_path / "site" / "gsplat"
    (package / "cuda" / "csrc").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "cuda" / "csrc" / "Adam.cu").write_text("")
    monkeypatch.setattr(steps, "EXTENSIONS_DIR", str(tmp_path / "ext"))
    monkeypatch.setattr(torch.cuda, "get_device_capability", lambda: (9, 0))  # an H100/H200
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name: types.SimpleNamespace(origin=str(package / "__init__.py")))
    monkeypatch.setattr(os, "environ", dict(os.environ))
    chk = _Check()
    saved = tmp_path / "again.tar.gz"
    rec = steps.build_gsplat(chk, reuse=str(archive), save=str(saved))
    so = tmp_path / "ext" / "gsplat_cuda" / "gsplat_cuda.so"
    assert so.read_bytes() == b"so" and so.stat().st_mtime == 1.9e9
    assert (package / "cuda" / "csrc" / "Adam.cu").stat().st_mtime < so.stat().st_mtime
    assert rec["reused_archive"] and chk.ran[0][0] == "build_gsplat"
    assert chk.ran[0][1]["TORCH_EXTENSIONS_DIR"] == str(tmp_path / "ext")
    assert chk.ran[0][1]["TORCH_CUDA_ARCH_LIST"] == "9.0"  # built for this GPU only
    with tarfile.open(saved) as tar:  # what a later GPU run would unpack
        assert "./gsplat_cuda/gsplat_cuda.so" in tar.getnames()


def test_without_an_archive_the_build_compiles_as_before(tmp_path, monkeypatch):
    monkeypatch.setattr(steps, "EXTENSIONS_DIR", str(tmp_path / "ext"))
    monkeypatch.setattr(torch.cuda, "get_device_capability", lambda: (9, 0))  # an H100/H200
    monkeypatch.setattr(os, "environ", dict(os.environ))
    rec = steps.build_gsplat(_Check(), reuse=str(tmp_path / "missing.tar.gz"))
    assert rec["reused_archive"] is False


def _touch(path: Path, text: str = "") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_a_cut_run_reports_each_stage_and_the_geometry_checkpoint_it_resumes_from(tmp_path):
    cache = tmp_path / ".cache"
    _touch(cache / "masks" / "k1" / "masks.npz")
    for it in (1000, 2000):
        _touch(cache / "geometry" / "k2.partial" / "model" / "point_cloud" / f"iteration_{it}" / "point_cloud.ply")
    _touch(cache / "geometry" / "k2.partial" / "model" / "point_cloud" / "iteration_3000" / "unfinished.tmp")
    assert steps.run_progress(tmp_path) == {"geometry": [{"state": "cut", "checkpoint": 2000}],
                                                "masks": [{"state": "done"}]}


def test_the_figures_of_a_rerun_are_read_from_the_results_with_its_settings(tmp_path):
    import json

    base = {"run": {"overrides": ["a=1"]}, "which": "base"}
    rerun = {"run": {"overrides": ["a=1", "method.render_rule=visible"]}, "which": "rerun"}
    p_rerun = _touch(tmp_path / "trase" / "hypernerf" / "synthetic" / "c2" / "results.json", json.dumps(rerun))
    p_base = _touch(tmp_path / "trase" / "hypernerf" / "synthetic" / "c1" / "results.json", json.dumps(base))
    os.utime(p_rerun, (1, 1))  # the base run's results are the newest
    assert steps._run_figures(tmp_path)["results"]["which"] == "base"
    assert steps._run_figures(tmp_path, "method.render_rule=visible")["results"]["which"] == "rerun"
    assert "results" not in steps._run_figures(tmp_path, "method.render_rule=other")
    assert p_base.is_file()


def test_the_check_loads_its_modules_from_beside_it(capsys):
    """scripts/gpu_check.py runs from anywhere: its steps and workers are found beside it."""
    check = _load("gpu_check")
    assert check.profile.__module__ == "gpu_check_workers" and check.Check.__module__ == "gpu_check_steps"
    with pytest.raises(SystemExit) as done:
        check.main(["watch", "--help"])
    assert done.value.code == 0 and "--variants" in capsys.readouterr().out
