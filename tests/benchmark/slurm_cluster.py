"""A one-node SLURM on this machine for the sweep tests: Debian's munge and slurm-wlm daemons
(munged, slurmctld, slurmd) started in the foreground with a generated slurm.conf whose state,
spool, logs and munge socket live under one temporary folder, and stopped by pid.

The configuration is the smallest that runs batch jobs as a cluster would: cons_tres selection
of CPUs, proctrack/linuxproc and task/none (no cgroups needed), no accounting, one partition
``debug`` holding this node with its real CPU count and ``mem_mb`` of memory.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

DAEMONS = ("munged", "mungekey", "slurmctld", "slurmd", "sbatch", "squeue", "scontrol", "sinfo")


def why_not() -> str | None:
    """Why a test cluster cannot start here (None: it can)."""
    if not sys.platform.startswith("linux"):
        return "SLURM's daemons run on Linux only"
    if os.geteuid() != 0:
        return "starting slurmd needs root (it runs the jobs as their user)"
    missing = [d for d in DAEMONS if shutil.which(d) is None and not Path(f"/usr/sbin/{d}").exists()]
    if missing:
        return f"not installed: {', '.join(missing)} (Debian: apt-get install slurm-wlm munge; .ci/run does)"
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _exe(name: str) -> str:
    return shutil.which(name) or f"/usr/sbin/{name}"


class SlurmCluster:
    def __init__(self, root: Path, mem_mb: int = 4000) -> None:
        self.root = Path(root)
        self.mem_mb = mem_mb
        self.cpus = os.cpu_count() or 1
        self.host = socket.gethostname().split(".")[0]
        self.conf = self.root / "slurm.conf"
        self.procs: dict[str, subprocess.Popen] = {}

    @property
    def env(self) -> dict:
        return {"SLURM_CONF": str(self.conf)}

    def _write_conf(self) -> None:
        r = self.root
        self.conf.write_text("\n".join([
            "ClusterName=trasebench", f"SlurmctldHost={self.host}(127.0.0.1)",
            f"SlurmctldPort={_free_port()}", f"SlurmdPort={_free_port()}",
            "SlurmUser=root", "SlurmdUser=root", "AuthType=auth/munge", "CredType=cred/munge",
            f"AuthInfo=socket={r / 'munge' / 'socket'}",
            f"StateSaveLocation={r / 'state'}", f"SlurmdSpoolDir={r / 'spool'}",
            f"SlurmctldPidFile={r / 'slurmctld.pid'}", f"SlurmdPidFile={r / 'slurmd.pid'}",
            f"SlurmctldLogFile={r / 'log' / 'slurmctld.log'}", f"SlurmdLogFile={r / 'log' / 'slurmd.log'}",
            "ProctrackType=proctrack/linuxproc", "TaskPlugin=task/none",
            "SelectType=select/cons_tres", "SelectTypeParameters=CR_CPU",
            "SchedulerType=sched/backfill", "SchedulerParameters=sched_interval=2",
            "AccountingStorageType=accounting_storage/none", "JobAcctGatherType=jobacct_gather/none",
            "JobCompType=jobcomp/none", "MpiDefault=none", "ReturnToService=2", "InactiveLimit=0",
            "MinJobAge=3600", "KillWait=5", "SlurmdTimeout=60",
            f"NodeName={self.host} NodeAddr=127.0.0.1 CPUs={self.cpus} RealMemory={self.mem_mb} State=UNKNOWN",
            f"PartitionName=debug Nodes={self.host} Default=YES MaxTime=INFINITE State=UP", ""]))

    def _start(self, name: str, args: list[str]) -> None:
        log = open(self.root / "log" / f"{name}.out", "w")  # noqa: SIM115 - closed with the process
        self.procs[name] = subprocess.Popen([_exe(name), *args], stdout=log, stderr=subprocess.STDOUT,
                                            start_new_session=True, env={**os.environ, **self.env})

    def start(self, timeout: float = 60.0) -> SlurmCluster:
        for d in ("state", "spool", "log", "munge"):
            (self.root / d).mkdir(parents=True, exist_ok=True)
        os.chmod(self.root / "munge", 0o755)
        key = self.root / "munge" / "munge.key"
        subprocess.run([_exe("mungekey"), "--create", f"--keyfile={key}"], check=True, capture_output=True)
        m = self.root / "munge"
        self._start("munged", ["-F", "--force", f"--socket={m / 'socket'}", f"--key-file={key}",
                               f"--pid-file={m / 'munged.pid'}", f"--seed-file={m / 'seed'}",
                               f"--log-file={self.root / 'log' / 'munged.log'}"])
        self._wait(lambda: (m / "socket").exists(), timeout, "munged made no socket")
        self._write_conf()
        self._start("slurmctld", ["-D", "-f", str(self.conf)])
        self._start("slurmd", ["-D", "-f", str(self.conf)])
        self._wait(self._idle, timeout, "the node never became idle")
        return self

    def _idle(self) -> bool:
        out = subprocess.run(["sinfo", "-h", "-o", "%T"], capture_output=True, text=True,
                             env={**os.environ, **self.env}, check=False)
        return out.returncode == 0 and out.stdout.strip() == "idle"

    def _wait(self, ok, timeout: float, what: str) -> None:
        deadline = time.time() + timeout
        while not ok():
            dead = [n for n, p in self.procs.items() if p.poll() is not None]
            if dead or time.time() > deadline:
                logs = {n: (self.root / "log" / f"{n}.out").read_text()[-600:] for n in self.procs}
                self._stop_daemons()
                raise RuntimeError(f"test SLURM: {what} (stopped: {dead}); output: {logs}")
            time.sleep(0.2)

    def run(self, *cmd: str) -> str:
        out = subprocess.run(list(cmd), capture_output=True, text=True, env={**os.environ, **self.env}, check=True)
        return out.stdout

    def stop(self) -> None:
        """Cancel every job of this cluster (a failed test may leave some), stop the daemons, and
        end what still runs of its jobs: job steps outlive slurmd."""
        ctld = self.procs.get("slurmctld")
        if ctld is not None and ctld.poll() is None:
            env = {**os.environ, **self.env}
            subprocess.run(["scancel", "--partition=debug"], env=env, capture_output=True, check=False)
            deadline = time.time() + 30
            while time.time() < deadline:
                q = subprocess.run(["squeue", "-h"], env=env, capture_output=True, text=True, check=False)
                if q.returncode != 0 or not q.stdout.strip():
                    break
                time.sleep(0.5)
        self._stop_daemons()
        for pid in self._job_processes():
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass

    def _job_processes(self) -> list[int]:
        """Processes started by this cluster's slurmd (their environment names its slurm.conf)."""
        mark = f"SLURM_CONF={self.conf}".encode()
        out = []
        for d in Path("/proc").iterdir():
            if not d.name.isdigit() or int(d.name) == os.getpid():
                continue
            try:
                if mark in (d / "environ").read_bytes().split(b"\0"):
                    out.append(int(d.name))
            except OSError:
                continue
        return out

    def _stop_daemons(self) -> None:
        for name in ("slurmd", "slurmctld", "munged"):
            p = self.procs.pop(name, None)
            if p is None or p.poll() is not None:
                continue
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=15)
