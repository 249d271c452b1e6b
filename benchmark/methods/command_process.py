"""Running a command method's program: its own process group, its output to a log file, a
timeout; nothing of it left running afterwards (benchmark.methods.command)."""

from __future__ import annotations

import dataclasses
import datetime
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

# the toolkit's own interpreter settings: a method in its own environment must not import the
# toolkit's packages by accident (a TOML's [env] may set them)
NOT_INHERITED = ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "PYTHONSTARTUP")
TERM_GRACE_S = 5.0  # between SIGTERM and SIGKILL of a command past its timeout


@dataclasses.dataclass
class Finished:
    argv: list[str]
    status: int | None  # the exit status (negative: killed by that signal); None: stopped at the timeout
    seconds: float
    timed_out: bool
    error: str | None = None  # the program could not be started (not found, not executable)

    @property
    def ok(self) -> bool:
        return self.status == 0 and not self.timed_out and self.error is None

    def problem(self, timeout: float) -> str:
        """What went wrong, in words (empty when it succeeded)."""
        if self.error:
            return f"could not start {self.argv[0]!r} ({self.error})"
        if self.timed_out:
            return f"still running after its timeout of {timeout:g} s (stopped)"
        if self.status is not None and self.status < 0:
            return f"killed by signal {-self.status}"
        return f"exit status {self.status}" if self.status else ""


def toolkit_bin_dirs() -> set[Path]:
    """The toolkit's virtual environment's executables folders (none where the toolkit runs
    from a system interpreter): an activated environment puts its ``python3`` first on PATH,
    and a method's ``python3`` must not be the toolkit's."""
    prefixes = [sys.prefix] if sys.prefix != sys.base_prefix else []
    prefixes += [os.environ["VIRTUAL_ENV"]] if os.environ.get("VIRTUAL_ENV") else []
    return {(Path(p) / "bin").resolve() for p in prefixes}


def command_env(extra: dict[str, str]) -> dict[str, str]:
    """This process's environment without NOT_INHERITED and without the toolkit's environment's
    executables on PATH, plus ``extra`` (a TOML's [env], which may set them on purpose)."""
    env = {k: v for k, v in os.environ.items() if k not in NOT_INHERITED}
    hidden = toolkit_bin_dirs()
    if "PATH" in env:
        env["PATH"] = os.pathsep.join(d for d in env["PATH"].split(os.pathsep) if d and Path(d).resolve() not in hidden)
    return env | dict(extra)


def run_logged(argv: list[str], cwd: Path, env: dict[str, str], timeout: float, log: Path) -> Finished:
    """Run ``argv`` in ``cwd`` in a process group of its own, stdout and stderr to ``log``
    (written anew, headed by the command), stopped after ``timeout`` seconds (SIGTERM to the
    group, then SIGKILL after TERM_GRACE_S); any process of the group still alive when the
    command ends is killed too, and so is the group when this process is interrupted."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "wb") as f:
        now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        f.write(f"# command: {shlex.join(argv)}\n# workdir: {cwd}\n# timeout: {timeout:g} s\n# started: {now}\n"
                .encode())
        f.flush()
        t0 = time.monotonic()
        try:
            proc = subprocess.Popen(argv, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=f,
                                    stderr=subprocess.STDOUT, start_new_session=True)
        except OSError as exc:
            reason = exc.strerror or type(exc).__name__
            f.write(f"# could not start: {reason}\n".encode())
            return Finished(list(argv), None, 0.0, False, reason)
        timed_out = False
        try:
            status = proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            timed_out = True
            status = _stop_group(proc)
        except BaseException:  # interrupted: never leave the command running
            _stop_group(proc)
            raise
        finally:
            _kill_group(proc.pid)  # what it left running behind it
        seconds = time.monotonic() - t0
        end = f"stopped after its timeout of {timeout:g} s" if timed_out else f"exit status {status}"
        f.write(f"\n# {end}, {seconds:.1f} s\n".encode())
    return Finished(list(argv), None if timed_out else status, seconds, timed_out)


def _stop_group(proc: subprocess.Popen) -> int:
    """SIGTERM to the command's group, SIGKILL after TERM_GRACE_S; its exit status."""
    _signal_group(proc.pid, signal.SIGTERM)
    try:
        return proc.wait(timeout=TERM_GRACE_S)
    except subprocess.TimeoutExpired:
        _signal_group(proc.pid, signal.SIGKILL)
        return proc.wait()


def _kill_group(pgid: int) -> None:
    _signal_group(pgid, signal.SIGKILL)


def _signal_group(pgid: int, sig: int) -> None:
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):  # the group is gone
        pass


__all__ = ["NOT_INHERITED", "Finished", "command_env", "run_logged", "toolkit_bin_dirs"]
