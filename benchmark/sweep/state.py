"""A sweep job's state: its file under ``<out>/.sweep/<name>/jobs/`` (written by the worker,
locked), read and reconciled with the scheduler's view; the task a worker runs."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import time
from pathlib import Path

from benchmark.stage_lock import known_dead
from benchmark.sweep.spec import SweepJob, SweepTarget

IN_FLIGHT = ("queued", "running", "requeued")  # a rerun leaves these alone


def state_path(where, job: SweepJob) -> Path:
    """``where``: a SweepTarget, or a SweepSpec (its target)."""
    return where.state_dir / "jobs" / f"{job.id}.json"


@contextlib.contextmanager
def state_lock(where, job: SweepJob):
    """One writer of a job's state file at a time: the submitter and the job's worker both
    write it, and an atomic write sweeps away another writer's temporary (trase.io), so two at
    once could fail; the submitter's read-then-write must not put back a state older than the
    worker's. The lock is the stage cache's (benchmark.stage_lock: NFS-safe, a dead holder's
    lock broken)."""
    from benchmark.stage_lock import StageLock

    lock = StageLock(state_path(where, job).with_suffix(".lock"))
    while not lock.acquire():
        holder = lock.holder()
        if lock.is_stale(holder):
            lock.break_stale(holder)
        time.sleep(0.02)
    try:
        yield
    finally:
        lock.release()


def write_state(where, job: SweepJob, **fields) -> None:
    from benchmark.io import atomic_write_json

    with state_lock(where, job):
        atomic_write_json(state_path(where, job), {"job": job.id, "label": job.label(), "definition": job.to_dict(),
                                                   "time": time.time(), **fields})


def read_state_file(target, job: SweepJob) -> dict | None:
    p = state_path(target, job)
    try:
        return json.loads(p.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError):
        return {"state": "pending", "note": f"{p}: unreadable state"}


_UNREAD = object()


def read_state(target, job: SweepJob, scheduler: dict | None = None, written=_UNREAD) -> dict:
    """The job's state as its worker wrote it, reconciled with the scheduler's view
    (``scheduler``: {scheduler id: benchmark.scheduler.SchedulerJob}, None: not asked):
    pending, queued, running, requeued, done, failed, cancelled, timed out, died or lost.
    ``written``: the state file's content when the caller has read it already."""
    st = read_state_file(target, job) if written is _UNREAD else written
    if st is None:
        return {"state": "pending"}
    state = st.get("state")
    if state == "done" and not all(Path(r).is_file() for r in st.get("results", [])):
        return {**st, "state": "pending", "note": "its results are gone"}
    if state not in ("submitted", "running"):
        return st
    sched = (scheduler or {}).get(str(st.get("scheduler_id") or ""))
    alive = _worker_alive(st.get("host"), st.get("pid"))
    if sched is not None and sched.state != "unknown":
        said = f"SLURM: {sched.raw}" + (f" ({sched.reason})" if sched.reason else "") + (
            f", exit code {sched.exit_code}" if sched.exit_code and sched.state not in IN_FLIGHT else "")
        if sched.state in IN_FLIGHT:
            seen = sched.state if state == "submitted" or sched.state != "queued" else "requeued"
            return {**st, "state": seen, "scheduler": said}
        if state == "running" and alive is True:  # the scheduler finished before the worker's last write
            return {**st, "scheduler": said}
        ended = {"cancelled": "cancelled", "timed out": "timed out", "preempted": "cancelled"}.get(sched.state)
        if ended:
            return {**st, "state": ended, "scheduler": said}
        why = "before it started" if state == "submitted" else "without a word from the worker"
        return {**st, "state": "died", "scheduler": said, "error": f"ended {why} ({said})"}
    if state == "submitted":
        if st.get("executor") == "local" and alive is True:
            return {**st, "state": "queued"}  # its local worker is alive and will come to it
        if st.get("executor") == "slurm" and scheduler is None:
            return {**st, "state": "queued", "note": "SLURM not asked"}
        return {**st, "state": "lost", "error": "it never started and its scheduler no longer holds it"}
    if alive is False:
        return {**st, "state": "died", "error": st.get("error") or "the worker stopped without a word (killed?)"}
    if sched is not None and st.get("executor") == "slurm" and alive is not True:
        return {**st, "state": "lost", "error": "SLURM no longer holds the job its worker said was running"}
    return st


def _worker_alive(host, pid) -> bool | None:
    """Whether a worker process runs: known only for a pid of this machine (None elsewhere)."""
    if host != socket.gethostname() or not isinstance(pid, int):
        return None
    return not known_dead(host, pid)


def scheduler_view(written: list[dict | None]) -> dict | None:
    """SLURM's view of the jobs submitted to it that are not finished by their own account
    (``written``: their state files' contents; None when none was, so no SLURM command runs)."""
    ids = [str(st["scheduler_id"]) for st in written
           if st and st.get("executor") == "slurm" and st.get("state") in ("submitted", "running")
           and st.get("scheduler_id")]
    if not ids:
        return None
    from benchmark.scheduler import slurm_jobs

    return slurm_jobs(ids)


def run_job(target, job: SweepJob, log: str | None = None, task_id: str | None = None,
            executor: str | None = None) -> list[str]:
    """Run one job here and record its state (with the scheduler's task id when run by one);
    returns its results.json paths."""
    from benchmark.errors import is_user_error
    from benchmark.runner import run

    target = getattr(target, "target", target)
    threads = {"omp_wait_policy": os.environ.get("OMP_WAIT_POLICY")}  # beside its seconds: how idle threads waited
    write_state(target, job, state="running", host=socket.gethostname(), pid=os.getpid(), started=time.time(),
                log=log, scheduler_id=task_id, executor=executor, **threads)
    print(f"[{time.strftime('%H:%M:%S')}] job {job.id}: {job.label()}", flush=True)
    t0 = time.time()
    try:
        paths = [str(p) for p in run(target.run_options(job))]
    except Exception as exc:
        line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        error = line if is_user_error(exc) else f"{type(exc).__name__}: {line}"
        write_state(target, job, state="failed", error=error, log=log, seconds=time.time() - t0,
                    scheduler_id=task_id, executor=executor, **threads)
        print(f"[{time.strftime('%H:%M:%S')}] job {job.id} failed: {error}", flush=True)
        raise
    write_state(target, job, state="done", results=paths, log=log, seconds=time.time() - t0,
                scheduler_id=task_id, executor=executor, **threads)
    print(f"[{time.strftime('%H:%M:%S')}] job {job.id} done in {time.time() - t0:.0f}s: {', '.join(paths)}", flush=True)
    return paths


class SweepJobsFailed(RuntimeError):
    """A task's jobs failed: raised after all of them ran, so the worker exits non-zero."""


class SweepTask:
    """What a submitit job runs: its share of the sweep's jobs, in order, as they were frozen at
    submission (the spec file is not read again). Checkpointable: on preemption or timeout
    SLURM requeues it, and the stage cache (and the stages' own checkpoints) make the rerun
    resume. Ends with an error when any of its jobs failed, so the scheduler records FAILED."""

    def __init__(self, target: dict, jobs: list[dict], executor: str = "local") -> None:
        self.target, self.jobs, self.executor = target, jobs, executor

    @property
    def job_ids(self) -> list[str]:
        return [SweepJob.from_dict(d).id for d in self.jobs]

    def __call__(self) -> dict:
        target = SweepTarget.from_dict(self.target)
        log, task_id = None, None
        try:
            import submitit

            env = submitit.JobEnvironment()
            log, task_id = str(env.paths.stdout), str(env.job_id)
        except RuntimeError:  # not inside a submitit job (tests call it directly)
            pass
        done, failed = [], []
        for d in self.jobs:
            job = SweepJob.from_dict(d)
            if read_state(target, job)["state"] == "done":
                done.append(job.id)
                continue
            try:
                run_job(target, job, log, task_id, self.executor)
                done.append(job.id)
            except Exception:  # noqa: BLE001 - recorded in the job's state; the next job runs
                failed.append(job.id)
        if failed:
            raise SweepJobsFailed(f"{len(failed)} of {len(self.jobs)} job(s) failed: {', '.join(failed)} "
                                  "(their errors: trase-bench sweep-status)")
        return {"done": done, "failed": failed}

    def checkpoint(self, *args, **kwargs):
        import submitit

        return submitit.helpers.DelayedSubmission(self)
