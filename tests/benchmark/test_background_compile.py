"""Kernels compiled beside a scene's generation: started, waited for, stopped on failure."""

from __future__ import annotations

import json
import subprocess
import sys
import typing

import pytest

from benchmark import background_compile as bc


class _FakePopen:
    """Stands in for the precompile process; records what the context manager did to it."""

    instances: typing.ClassVar[list] = []

    def __init__(self, args, returncode=0, message="", running=False, stderr=None, **kwargs):
        self.args, self.returncode, self._running = args, returncode, running
        self.killed = False
        if stderr is not None:
            stderr.write(message)  # what the process would have written to its error file
        _FakePopen.instances.append(self)

    def poll(self):
        return None if self._running else self.returncode

    def kill(self):
        self.killed = True

    def wait(self, timeout=None):
        self._running = False
        return self.returncode


@pytest.fixture
def fake(monkeypatch):
    _FakePopen.instances = []
    monkeypatch.setenv(bc.ENV, "1")

    def use(**kw):
        monkeypatch.setattr(bc.subprocess, "Popen", lambda args, **k: _FakePopen(args, **{**k, **kw}))
        return _FakePopen.instances

    return use


def test_it_starts_the_precompiler_and_waits_for_it(fake):
    procs = fake(running=True)
    lines = []
    with bc.kernels_compiled_meanwhile(echo=lines.append):
        assert procs and procs[0].args[-3:] == ["-m", "trase.precompile", "--quiet"]
        assert procs[0].args[0] == sys.executable
    assert not procs[0].killed and procs[0]._running is False
    assert len(lines) == 1 and lines[0].startswith("trase-bench: waiting for the numba kernels")


def test_a_failing_precompiler_is_one_line_and_the_run_goes_on(fake):
    fake(returncode=3, message="Traceback ...\nRuntimeError: boom\n")
    lines = []
    with bc.kernels_compiled_meanwhile(echo=lines.append):
        pass
    assert lines == [("trase-bench: the kernel compilation alongside failed (exit 3: RuntimeError: boom); "
                      "kernels compile on first use")]


def test_a_failing_body_stops_the_precompiler(fake):
    procs = fake(running=True)
    with pytest.raises(KeyboardInterrupt), bc.kernels_compiled_meanwhile(echo=lambda m: None):
        raise KeyboardInterrupt
    assert procs[0].killed


def test_off_by_environment(fake, monkeypatch):
    procs = fake()
    monkeypatch.setenv(bc.ENV, "0")
    with bc.kernels_compiled_meanwhile(echo=lambda m: None):
        pass
    assert procs == []


def test_the_command_it_starts_exists():
    """``python -m trase.precompile`` is importable and answers (its run: tests/trase/test_precompile.py)."""
    done = subprocess.run([sys.executable, "-m", "trase.precompile", "--help"], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0 and "numba" in done.stdout


def test_ensure_synthetic_compiles_alongside_only_when_it_generates(fake, monkeypatch, tmp_path):
    from benchmark.datasets.synthetic import cache

    def fake_generate(dataset, out, **kw):
        (out / "synthetic").mkdir(parents=True)
        (out / "synthetic" / "manifest.json").write_text(json.dumps({"generator_version": cache.GENERATOR_VERSION}))

    monkeypatch.setattr(cache, "generate", fake_generate)
    procs = fake()
    cache.ensure_synthetic("hypernerf", size="tiny", cache_dir=tmp_path)  # the default: no
    assert procs == []
    cache.ensure_synthetic("nerfds", size="tiny", cache_dir=tmp_path, precompile=True)
    assert len(procs) == 1
    cache.ensure_synthetic("nerfds", size="tiny", cache_dir=tmp_path, precompile=True)  # cached now
    assert len(procs) == 1
