"""The kernel precompiler: its miniature leaves every kernel a run needs in numba's cache."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from trase.precompile import compile_kernels, main


def test_the_miniature_runs_and_a_second_call_compiles_nothing(capsys):
    compile_kernels()  # whatever this process had not compiled yet
    out = compile_kernels()
    assert out["compiled"] == []
    assert out["seconds"] > 0
    assert main([]) == 0
    assert "trase kernels: all cached" in capsys.readouterr().out


def test_the_miniature_stays_on_the_cpu_where_torch_sees_a_gpu(monkeypatch):
    """It warms the numba kernels: on a GPU machine ("auto" = cuda) it must not train there
    (it once did, and failed on a mixed-device render beside a run)."""
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert compile_kernels()["seconds"] > 0


@pytest.mark.slow
def test_a_fresh_process_finds_every_kernel_cached_after_precompile(tmp_path):
    """In an empty numba cache the first process compiles the kernels; the next one, running
    the same stages, compiles none (what a run after the background compilation sees)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}

    def precompile() -> str:
        done = subprocess.run([sys.executable, "-m", "trase.precompile"], env=env, capture_output=True,
                              text=True, timeout=900, check=False)
        assert done.returncode == 0, done.stderr
        return done.stdout

    first = precompile()
    assert "compiled in" in first and not first.startswith("trase kernels: 0 ")
    assert "trase kernels: all cached" in precompile()
