"""What SLURM knows about a sweep's jobs and nodes, asked with its own commands.

``slurm_jobs`` reads ``scontrol show job -o`` (every job slurmctld holds: queued, running, and
the finished ones for ``MinJobAge``) and, for ids it no longer holds, ``sacct`` where the
cluster keeps accounting; ``partition_nodes`` reads ``sinfo`` (what each node of a partition
has), so a request no node can satisfy is refused before ``sbatch`` queues it forever.
Every failure of these commands is a one-line ``SchedulerError``; nothing here submits.
"""

from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess
from collections.abc import Iterable

from benchmark.errors import UserError

# SLURM's job states (squeue/scontrol/sacct words) -> what a sweep reports
STATES = {
    "PENDING": "queued", "REQUEUED": "requeued", "REQUEUE_HOLD": "requeued", "REQUEUE_FED": "requeued",
    "RUNNING": "running", "COMPLETING": "running", "CONFIGURING": "running", "SUSPENDED": "running",
    "STAGE_OUT": "running", "RESIZING": "running", "SIGNALING": "running", "STOPPED": "running",
    "COMPLETED": "completed", "FAILED": "failed", "NODE_FAIL": "failed", "BOOT_FAIL": "failed",
    "OUT_OF_MEMORY": "failed", "DEADLINE": "failed", "CANCELLED": "cancelled", "REVOKED": "cancelled",
    "TIMEOUT": "timed out", "PREEMPTED": "preempted",
}
ACTIVE = ("queued", "requeued", "running")  # the scheduler still holds the job: it will run or runs


class SchedulerError(UserError):
    pass


@dataclasses.dataclass(frozen=True)
class SchedulerJob:
    state: str  # one of STATES' values, or "unknown"
    raw: str  # SLURM's word (PENDING, RUNNING, ...)
    reason: str | None = None  # why it is pending, or how it ended
    exit_code: str | None = None  # "1:0": exit status and signal
    restarts: int = 0  # requeues so far


def _run(cmd: list[str], what: str) -> str:
    if shutil.which(cmd[0]) is None:
        raise SchedulerError(f"{cmd[0]} not found: SLURM's commands are needed for {what} (is this a SLURM login "
                             "node? else use --executor local)")
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=60, check=False)
    except subprocess.TimeoutExpired:
        raise SchedulerError(f"{' '.join(cmd[:2])}: no answer in 60 s (slurmctld busy or unreachable)") from None
    if out.returncode != 0:
        msg = (out.stderr or out.stdout).strip().splitlines()
        raise SchedulerError(f"{' '.join(cmd[:2])} failed: {msg[-1] if msg else f'exit code {out.returncode}'}")
    return out.stdout


def expand_tasks(spec: str) -> list[int]:
    """An array's pending task list as scontrol writes it ("0-3%2", "1,4-6") -> task ids."""
    out: list[int] = []
    for part in spec.split("%", 1)[0].split(","):
        if "-" in part:
            a, b = part.split("-", 1)
            out += range(int(a), int(b) + 1)
        elif part.strip():
            out.append(int(part))
    return out


def _fields(line: str) -> dict[str, str]:
    """``Key=Value Key=Value ...`` of one ``scontrol -o`` line (values without spaces, except the
    last keys' free text, which is not read)."""
    return dict(m.groups() for m in re.finditer(r"(\w+)=(\S*)", line))


def parse_scontrol(text: str) -> dict[str, SchedulerJob]:
    """``scontrol show job -o`` -> {job id: SchedulerJob}; array tasks under ``ARRAY_TASK`` ids
    (``123_4``, as submitit names them), a pending range once per task it holds."""
    jobs: dict[str, SchedulerJob] = {}
    for line in text.splitlines():
        f = _fields(line)
        if "JobId" not in f:
            continue
        raw = f.get("JobState", "UNKNOWN")
        reason = f.get("Reason")
        job = SchedulerJob(STATES.get(raw, "unknown"), raw, None if reason in (None, "None") else reason,
                           f.get("ExitCode"), int(f.get("Restarts", "0") or 0))
        if job.state == "queued" and job.restarts > 0:
            job = dataclasses.replace(job, state="requeued")
        array, task = f.get("ArrayJobId"), f.get("ArrayTaskId")
        if array and task:
            for t in expand_tasks(task):
                jobs[f"{array}_{t}"] = job
        else:
            jobs[f["JobId"]] = job
    return jobs


def parse_sacct(text: str) -> dict[str, SchedulerJob]:
    """``sacct -n -P -o JobID,State,ExitCode`` -> {job id: SchedulerJob} (steps left out)."""
    jobs = {}
    for line in text.splitlines():
        parts = line.split("|")
        if len(parts) < 3 or "." in parts[0]:
            continue
        raw = parts[1].split()[0] if parts[1] else "UNKNOWN"  # "CANCELLED by 0"
        jobs[parts[0]] = SchedulerJob(STATES.get(raw, "unknown"), raw, None, parts[2] or None)
    return jobs


def slurm_jobs(ids: Iterable[str]) -> dict[str, SchedulerJob]:
    """SLURM's view of ``ids`` (``123`` or array tasks ``123_4``); an id it no longer knows is
    ``unknown`` (finished longer ago than MinJobAge on a cluster without accounting)."""
    ids = sorted(set(ids))
    if not ids:
        return {}
    text = _run(["scontrol", "show", "job", "-o"], "the sweep's job states")
    known = parse_scontrol("" if text.strip().startswith("No jobs") else text)
    out = {i: known[i] for i in ids if i in known}
    missing = [i for i in ids if i not in out]
    if missing and shutil.which("sacct"):
        acct = subprocess.run(["sacct", "-n", "-P", "-X", "-o", "JobID,State,ExitCode", "-j", ",".join(missing)],
                              capture_output=True, text=True, timeout=60, check=False)
        if acct.returncode == 0:  # no accounting: sacct says so and fails; the ids stay unknown
            out |= {i: j for i, j in parse_sacct(acct.stdout).items() if i in missing}
    return out | {i: SchedulerJob("unknown", "UNKNOWN") for i in ids if i not in out}


@dataclasses.dataclass(frozen=True)
class NodeResources:
    name: str
    cpus: int
    mem_mb: int
    gpus: int


def parse_gres_gpus(gres: str) -> int:
    """``gpu:a100:4(S:0-1),shard:8`` -> 4 (the node's GPUs; 0 for "(null)")."""
    n = 0
    for item in gres.split(","):
        parts = item.split("(", 1)[0].split(":")
        if parts[0] == "gpu":
            n += int(parts[-1]) if len(parts) > 1 and parts[-1].isdigit() else 1
    return n


def partition_nodes(partition: str | None) -> tuple[str, list[NodeResources]]:
    """(the partition's name, what each of its nodes has) from ``sinfo``; ``None``: the
    default partition. An unknown partition is a one-line error naming the known ones."""
    text = _run(["sinfo", "-h", "-N", "-o", "%P|%N|%c|%m|%G"], "checking the request against the partition")
    rows = [line.split("|") for line in text.splitlines() if line.count("|") == 4]
    names = sorted({r[0].rstrip("*") for r in rows})
    if partition is None:
        default = [r[0].rstrip("*") for r in rows if r[0].endswith("*")]
        if not default:
            raise SchedulerError("no partition given and the cluster has no default one (sinfo); "
                                 f"give --partition ({', '.join(names) or 'none known'})")
        partition = default[0]
    nodes = [NodeResources(r[1], int(r[2].rstrip("+")), int(r[3].rstrip("+")), parse_gres_gpus(r[4]))
             for r in rows if r[0].rstrip("*") == partition]
    if not nodes:
        raise SchedulerError(f"partition {partition!r} does not exist (sinfo knows: {', '.join(names) or 'none'})")
    return partition, nodes


def check_request(name: str, nodes: list[NodeResources], cpus: int, mem_gb: int, gpus: int) -> None:
    """Refuse a request that no node of partition ``name`` (its ``nodes``, ``partition_nodes``)
    can satisfy: SLURM would queue it forever, reason PartitionConfig or Resources."""
    fits = [n for n in nodes if n.cpus >= cpus and n.mem_mb >= mem_gb * 1024 and n.gpus >= gpus]
    if not fits:
        most_cpus, most_mem, most_gpus = (max(getattr(n, k) for n in nodes) for k in ("cpus", "mem_mb", "gpus"))
        over = [text for text, too_big in (
            (f"--cpus-per-task {cpus} (largest node: {most_cpus})", cpus > most_cpus),
            (f"--mem {mem_gb} GB (largest node: {most_mem / 1024:.1f} GB)", mem_gb * 1024 > most_mem),
            (f"--gpus {gpus} (largest node: {most_gpus})", gpus > most_gpus)) if too_big]
        raise SchedulerError(f"partition {name!r} has no node with what each job asks: "
                             + ("; ".join(over) or "no single node has all of it together"))
