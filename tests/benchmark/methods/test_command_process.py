"""Running a command method's program (benchmark.methods.command_process): its log, its exit
status, its environment, and nothing of it left running after a timeout."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from benchmark.methods import command_process
from benchmark.methods.command_process import command_env, run_logged


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting for its parent to reap it does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, IndexError):
        return False
    return state not in ("Z", "X")


def _py(code: str) -> list[str]:
    return [sys.executable, "-c", code]


def test_exit_status_and_log(tmp_path):
    log = tmp_path / "logs" / "command.log"
    done = run_logged(_py("import sys; print('to stdout'); print('to stderr', file=sys.stderr); sys.exit(4)"),
                      tmp_path, command_env({}), 30, log)
    assert done.status == 4 and not done.ok and not done.timed_out and done.problem(30) == "exit status 4"
    text = log.read_text()
    assert text.startswith(f"# command: {sys.executable} -c ") and f"# workdir: {tmp_path}" in text
    assert "to stdout" in text and "to stderr" in text and text.rstrip().endswith(f"exit status 4, {done.seconds:.1f} s")
    ok = run_logged(_py("pass"), tmp_path, command_env({}), 30, log)
    assert ok.ok and ok.problem(30) == "" and "to stdout" not in log.read_text()  # a log is written anew


def test_the_environment_leaves_out_the_toolkits_python_settings(tmp_path, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", "/the/toolkit")
    monkeypatch.setenv("TRASE_TEST_INHERITED", "yes")
    env = command_env({"EXTRA": "1"})
    assert "PYTHONPATH" not in env and env["TRASE_TEST_INHERITED"] == "yes" and env["EXTRA"] == "1"
    assert command_env({"PYTHONPATH": "/mine"})["PYTHONPATH"] == "/mine"  # a TOML's [env] may set it
    log = tmp_path / "log"
    run_logged(_py("import os; print(os.environ.get('PYTHONPATH'), os.getcwd())"), tmp_path, env, 30, log)
    assert f"None {tmp_path}" in log.read_text()


def test_a_timeout_stops_the_whole_process_group(tmp_path):
    pids = tmp_path / "pids"
    code = ("import subprocess, sys, time\n"
            "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
            f"open({str(pids)!r}, 'w').write(f'{{child.pid}}')\n"
            "time.sleep(60)")
    t0 = time.monotonic()
    done = run_logged(_py(code), tmp_path, command_env({}), 1.0, tmp_path / "log")
    assert done.timed_out and done.status is None and time.monotonic() - t0 < 10
    assert done.problem(1.0) == "still running after its timeout of 1 s (stopped)"
    assert "stopped after its timeout of 1 s" in (tmp_path / "log").read_text()
    deadline = time.monotonic() + 5
    while alive(int(pids.read_text())) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(int(pids.read_text()))  # the command's own child too


def test_a_command_ignoring_sigterm_is_killed(tmp_path, monkeypatch):
    monkeypatch.setattr(command_process, "TERM_GRACE_S", 0.5)
    code = "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('ready', flush=True); time.sleep(60)"
    done = run_logged(_py(code), tmp_path, command_env({}), 1.0, tmp_path / "log")
    assert done.timed_out and done.status is None


def test_what_a_command_leaves_running_is_stopped(tmp_path):
    pids = tmp_path / "pids"
    code = ("import subprocess, sys\n"
            "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
            f"open({str(pids)!r}, 'w').write(f'{{child.pid}}')")
    done = run_logged(_py(code), tmp_path, command_env({}), 30, tmp_path / "log")
    assert done.ok
    deadline = time.monotonic() + 5
    while alive(int(pids.read_text())) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(int(pids.read_text()))


def test_a_program_that_cannot_start(tmp_path):
    done = run_logged([str(tmp_path / "no-such-program")], tmp_path, command_env({}), 30, tmp_path / "log")
    assert not done.ok and done.error and "could not start" in done.problem(30)
    assert "# could not start" in (tmp_path / "log").read_text()
    script = tmp_path / "not-executable.sh"
    script.write_text("#!/bin/sh\n")
    done = run_logged([str(script)], tmp_path, command_env({}), 30, tmp_path / "log")
    assert "Permission denied" in done.problem(30)  # no execute bit: not even root may run it


def test_a_method_launched_from_the_activated_toolkit_cannot_import_it(tmp_path, monkeypatch):
    """An activated environment puts the toolkit's python3 first on PATH; the method's
    ``python3`` is then another interpreter (the system's here), which cannot import the toolkit."""
    import shutil

    venv_bin = Path(sys.prefix) / "bin"
    monkeypatch.setenv("PATH", f"{venv_bin}:{command_process.os.environ.get('PATH', '')}")
    monkeypatch.setenv("VIRTUAL_ENV", sys.prefix)
    monkeypatch.delenv("PYTHONPATH", raising=False)
    env = command_env({})
    if sys.prefix == sys.base_prefix:
        pytest.skip("the toolkit runs from a system interpreter: no environment of its own to hide")
    assert venv_bin.resolve() not in {Path(d).resolve() for d in env["PATH"].split(":") if d}
    python3 = shutil.which("python3", path=env["PATH"])
    if python3 is None:
        pytest.skip("no other python3 on this machine's PATH to launch")
    log = tmp_path / "log"
    done = run_logged([python3, "-c", "import benchmark"], tmp_path, env, 30, log)
    assert not done.ok and "No module named 'benchmark'" in log.read_text()
