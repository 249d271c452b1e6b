"""The numeric modes (benchmark.numerics): which mode a command asks for, the environment each
sets, and the check that a run's process computes in its mode."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from benchmark import numerics
from benchmark.cli import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("argv, mode", [
    (["run", "--set", "machine.numerics=native"], "native"),
    (["run", "--set=machine.numerics=native", "--set", "seed=1"], "native"),
    (["run", "--set", "seed=1"], None),
    (["run", "--set"], None),
])
def test_the_mode_of_a_command_line(argv, mode):
    assert numerics.mode_from_argv(argv) == mode


def test_an_unknown_mode_is_one_line(monkeypatch):
    monkeypatch.delenv(numerics.ENV_MODE, raising=False)
    with pytest.raises(numerics.NumericsError, match="machine.numerics=fast: choose portable or native"):
        numerics.requested_mode(["--set", "machine.numerics=fast"])
    assert numerics.requested_mode([]) == "portable"


def test_portable_sets_every_library_and_native_unsets_them():
    with numerics.environment("native"):
        assert not any(k in os.environ for k in numerics.PORTABLE_ENV)
        assert os.environ[numerics.ENV_MODE] == "native"
        with numerics.environment("portable"):
            assert {k: os.environ[k] for k in numerics.PORTABLE_ENV} == numerics.PORTABLE_ENV
        assert "ATEN_CPU_CAPABILITY" not in os.environ
    assert os.environ["ATEN_CPU_CAPABILITY"] == "avx2"  # the suite's own mode is back


def test_a_processor_without_the_baseline_is_told_what_it_lacks(monkeypatch):
    monkeypatch.setattr(numerics, "host_features", lambda: set(numerics.BASELINE_FEATURES) - {"avx2", "fma"})
    with pytest.raises(numerics.NumericsError, match=r"lacks avx2, fma: run with --set machine.numerics=native"):
        numerics.check("portable")
    monkeypatch.setattr(numerics, "host_features", lambda: None)  # not x86-64
    with pytest.raises(numerics.NumericsError, match="pin x86-64 code"):
        numerics.check("portable")


def test_a_run_in_a_process_loaded_under_another_mode_stops_before_any_stage(tmp_path, capsys):
    # this process loaded numba, torch and numpy in portable mode: a native run cannot be computed here
    import numba  # noqa: F401
    import torch

    # torch fixes its kernel level at its first use: here, in portable mode, whatever ran before
    assert torch.backends.cpu.get_cpu_capability() == "AVX2"
    (tmp_path / "data").mkdir()  # a data root without real data: the built-in scene
    with numerics.environment("portable"):
        rc = main(["run", "--method", "trase", "--dataset", "hypernerf", "--data-root", str(tmp_path / "data"),
                   "--runs", str(tmp_path / "runs"), "--quiet", "--set", "machine.numerics=native"])
    err = capsys.readouterr().err
    assert rc == 1 and "machine.numerics=native, but this process computes otherwise" in err
    assert "numba compiles for x86-64-v3" in err
    assert not (tmp_path / "runs" / ".cache").exists()


def test_each_mode_loads_the_libraries_as_it_says():
    """In fresh processes: portable pins torch at AVX2 and numba at the baseline; native leaves
    them to the processor; each passes its own check."""
    code = ("import sys; from benchmark import numerics as n; m = sys.argv[1]; n.apply(m); "
            "import numpy, torch, numba, trase.blas_linear; n.check(m); d = n.kernels(); "
            "print(d['torch_cpu_capability'], d['numba_cpu'], d['products'])")
    out = {m: subprocess.run([sys.executable, "-c", code, m], cwd=ROOT, capture_output=True, text=True, check=True,
                             timeout=120).stdout.split() for m in numerics.MODES}
    assert out["portable"] == ["AVX2", "x86-64-v3", "openblas"]
    assert out["native"][1] != "x86-64-v3" and out["native"][2] == "torch"


def test_a_process_whose_network_products_are_not_its_mode_s_is_told(monkeypatch):
    from trase import blas_linear

    assert "products" not in numerics.live_mismatch("portable")  # this process: portable, OpenBLAS
    monkeypatch.setattr(blas_linear, "_engine", "torch")
    assert "the deformation network's products through torch" in numerics.live_mismatch("portable")


def test_a_record_says_the_mode_and_the_machine():
    d = numerics.describe("portable")
    assert d["mode"] == "portable" and d["baseline"] == "x86-64-v3" and d["env"] == numerics.PORTABLE_ENV
    assert d["pinning"] == numerics.PINNING
    assert "x86-64-v3" in d["x86_levels"] and d["cpu_model"]
    assert numerics.describe("native")["baseline"] == "native" and "env" not in numerics.describe("native")


def test_a_machine_that_cannot_give_portable_numerics_keeps_its_own_environment(monkeypatch):
    monkeypatch.setattr(numerics, "host_features", lambda: None)  # e.g. aarch64: no x86-64 target for numba
    with numerics.environment("native"):
        numerics.apply("portable")
        assert "NUMBA_CPU_NAME" not in os.environ and os.environ[numerics.ENV_MODE] == "native"
