"""A sweep submitted: the jobs neither done nor in flight, on this machine or through
submitit to SLURM (its resources checked against the partition), and the sweep's status and
results table."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
import socket
import sys
import time
from pathlib import Path

from benchmark import numerics
from benchmark.sweep.spec import SweepError, SweepJob, SweepSpec
from benchmark.sweep.state import (
    IN_FLIGHT,
    SweepTask,
    read_state,
    read_state_file,
    scheduler_view,
    state_lock,
    state_path,
    write_state,
)

DEFAULT_CPUS, DEFAULT_MEM_GB = 4, 16  # per job, each capped at the partition's largest node when not given


def status(spec: SweepSpec, ask_scheduler: bool = True, strict: bool = True) -> list[tuple[SweepJob, dict]]:
    """Every job of the spec with its reconciled state, then the jobs of earlier versions of the
    spec that are still in flight or finished (their state files), marked ``earlier_spec``.
    ``strict``: SLURM not answering is an error (what submission needs: it must not queue a job
    twice); otherwise the states are the workers' own, with a note saying why."""
    jobs = spec.jobs()
    written = {j.id: read_state_file(spec.target, j) for j in jobs}
    earlier = []
    for p in sorted((spec.state_dir / "jobs").glob("*.json")):
        if p.stem not in written:
            try:
                st = json.loads(p.read_text())
                job = SweepJob.from_dict(st["definition"])
            except (OSError, ValueError, KeyError, TypeError):
                continue  # a state file of an older layout or unreadable: not this sweep's business
            earlier.append(job)
            written[job.id] = st
    view, why = None, None
    if ask_scheduler:
        from benchmark.scheduler import SchedulerError

        try:
            view = scheduler_view(list(written.values()))
        except SchedulerError as exc:
            if strict:
                raise
            why = f"SLURM not asked: {exc}"

    def state(job: SweepJob, **extra) -> dict:
        st = read_state(spec.target, job, view, written[job.id])
        return {**st, **({"note": why} if why and st.get("executor") == "slurm" else {}), **extra}

    return [(j, state(j)) for j in jobs] + [(j, state(j, earlier_spec=True)) for j in earlier]


def pending_jobs(spec: SweepSpec, states: list[tuple[SweepJob, dict]] | None = None) -> list[SweepJob]:
    """The spec's jobs neither done nor queued/running/requeued (a rerun submits only these)."""
    states = status(spec) if states is None else states
    return [j for j, st in states if not st.get("earlier_spec") and st["state"] not in ("done", *IN_FLIGHT)]


def slurm_parameters(spec: SweepSpec) -> dict:
    """submitit's ``AutoExecutor.update_parameters`` arguments for the spec's [slurm] table
    (after ``resolve_resources``, the defaults capped to the partition's nodes)."""
    s = spec.slurm
    extra = {k: s[k] for k in ("account", "qos", "constraint") if k in s} | dict(s.get("additional", {}))
    p = {"name": f"trase-{spec.name}", "timeout_min": s.get("timeout_min", 60), "slurm_partition": s.get("partition"),
         "gpus_per_node": s.get("gpus_per_node", 0), "cpus_per_task": s.get("cpus_per_task", DEFAULT_CPUS),
         "mem_gb": s.get("mem_gb", DEFAULT_MEM_GB), "slurm_array_parallelism": s.get("array_parallelism", 16),
         "slurm_additional_parameters": extra or None}
    return {k: v for k, v in p.items() if v is not None}


def resolve_resources(spec: SweepSpec, echo=print) -> SweepSpec:
    """The spec with each job's request checked against the partition's nodes (sinfo): a
    request no node can satisfy is an error before submission; cpus and memory not given
    default to DEFAULT_CPUS / DEFAULT_MEM_GB, capped at the largest node (said so)."""
    from benchmark.scheduler import check_request, partition_nodes

    s = dict(spec.slurm)
    partition, nodes = partition_nodes(s.get("partition"))
    for key, default, have in (("cpus_per_task", DEFAULT_CPUS, max(n.cpus for n in nodes)),
                               ("mem_gb", DEFAULT_MEM_GB, max(n.mem_mb for n in nodes) // 1024)):
        if key not in s:
            s[key] = max(min(default, have), 1)
            if s[key] < default:
                echo(f"note: slurm.{key} not given: {s[key]} (the largest node of partition {partition!r} has "
                     f"{have}; default {default})")
    check_request(partition, nodes, s["cpus_per_task"], s["mem_gb"], s.get("gpus_per_node", 0))
    return dataclasses.replace(spec, slurm=s)


def sbatch_script(spec: SweepSpec, n_tasks: int) -> str:
    """The sbatch file submitit writes for the spec's job array of ``n_tasks`` (one task per
    job), made here without a cluster (submitit's own writer, fed the same parameters and the
    same log folder, so the log paths are the submitted ones)."""
    from submitit.slurm.slurm import _make_sbatch_string  # the writer SlurmExecutor submits with

    p = slurm_parameters(spec)
    native = {"job_name": p["name"], "time": p["timeout_min"], "partition": p.get("slurm_partition"),
              "gpus_per_node": p["gpus_per_node"], "cpus_per_task": p["cpus_per_task"], "mem": f"{p['mem_gb']}GB",
              "array_parallelism": p["slurm_array_parallelism"],
              "additional_parameters": p.get("slurm_additional_parameters")}
    command = f"{sys.executable} -u -m submitit.core._submit {spec.state_dir / 'logs'}"
    return _make_sbatch_string(command=command, folder=spec.state_dir / "logs", map_count=n_tasks,
                               **{k: v for k, v in native.items() if v is not None})


def submission_error(exc: BaseException) -> str:
    """A failed ``sbatch`` (submitit's FailedJobError with the command's whole output, or a
    missing program) -> its one telling line."""
    text = str(exc)
    said = [ln.strip() for ln in text.splitlines() if "sbatch: error:" in ln]
    if said:
        return "sbatch refused the jobs: " + said[0].split("sbatch: error:", 1)[1].strip()
    lines = [ln.strip() for ln in text.strip().splitlines() if ln.strip()]
    return f"submission failed: {type(exc).__name__}: {lines[-1] if lines else ''}"


PASSIVE_THREADS = {"OMP_WAIT_POLICY": "PASSIVE"}


@contextlib.contextmanager
def idle_threads_sleep(on: bool):
    """While submitting local workers that share this machine: their idle OpenMP threads sleep
    instead of spinning (``OMP_WAIT_POLICY=PASSIVE``, inherited by the workers; a value the user
    set is kept). Why: torch trains on two threads (the cpu presets' ``torch_threads``), and two
    such processes side by side on 2 loaded cores took 200-303 ms per step each with spinning
    threads against 92-99 ms passive (``scripts/measure_idle_threads.py``; docs/performance.md).
    Scheduling only: the numbers computed are the same."""
    added = {k: v for k, v in PASSIVE_THREADS.items() if on and k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for k in added:
            os.environ.pop(k, None)


def submit(spec: SweepSpec, wait: bool = True, echo=print, states: list | None = None) -> dict:
    """Submit the jobs neither done nor in flight: ``local``, ``workers`` processes on this
    machine (submitit's local executor), each running its share in order; ``slurm``, one array
    task per job, after checking the request against the partition. Each job is frozen in its
    state file before submission; if the submission fails, the earlier states are put back."""
    import submitit

    from benchmark.io import atomic_write_json

    states = status(spec) if states is None else states
    jobs = pending_jobs(spec, states)
    flying = [j for j, st in states if not st.get("earlier_spec") and st["state"] in IN_FLIGHT]
    if flying:
        echo(f"{len(flying)} job(s) already queued or running: not submitted again")
    if not jobs:
        return {"submitted": 0, "tasks": 0}
    mode = sweep_numerics(spec)  # the workers inherit its environment
    if spec.executor == "slurm":
        spec = resolve_resources(spec, echo)
    logs = spec.state_dir / "logs"
    target = spec.target.to_dict()
    if spec.executor == "local":
        ex = submitit.AutoExecutor(folder=logs, cluster="local")
        ex.update_parameters(timeout_min=int(spec.slurm.get("timeout_min", 24 * 60)))
        n = min(spec.workers, len(jobs))
        shares = [jobs[i::n] for i in range(n)]
    else:
        ex = submitit.AutoExecutor(folder=logs, cluster="slurm")
        ex.update_parameters(**slurm_parameters(spec))
        shares = [[j] for j in jobs]
    tasks = [SweepTask(target, [j.to_dict() for j in share], spec.executor) for share in shares]
    before = {j.id: read_state_file(spec.target, j) for j in jobs}  # read now: a worker may have written since status
    _freeze_spec(spec)
    for job in jobs:  # before submitting: a worker that starts at once overwrites it with running
        write_state(spec.target, job, state="submitted", executor=spec.executor, target=target,
                    host=socket.gethostname(), submitted=time.time())
    said = io.StringIO()  # sbatch's own output, which submitit copies to ours: the error below says it once
    try:
        with idle_threads_sleep(spec.executor == "local" and len(tasks) > 1), numerics.environment(mode), \
                contextlib.redirect_stderr(said), contextlib.redirect_stdout(said), ex.batch():
            handles = [ex.submit(t) for t in tasks]
    except Exception as exc:  # noqa: BLE001 - nothing was queued: the states go back, one line says why
        _restore(spec, jobs, before)
        raise SweepError(submission_error(exc)) from None
    for handle, share in zip(handles, shares):  # the scheduler's id, where no worker has written yet
        for job in share:
            with state_lock(spec.target, job):  # the worker may be writing "running" this instant
                st = read_state_file(spec.target, job) or {}
                if st.get("state") == "submitted":
                    fields = {"scheduler_id": str(handle.job_id), "log": str(handle.paths.stdout)}
                    if spec.executor == "local":  # submitit's local job id is its worker's pid
                        fields["pid"] = int(handle.job_id)
                    atomic_write_json(state_path(spec.target, job), {**st, **fields})
    echo(f"submitted {len(jobs)} job(s) as {len(handles)} {spec.executor} task(s); logs in {logs}")
    out = {"submitted": len(jobs), "tasks": len(handles), "scheduler_ids": [str(h.job_id) for h in handles]}
    if wait:
        for h in handles:
            try:
                h.result()
            except Exception as exc:  # noqa: BLE001 - each job's own state says what failed
                lines = [ln.strip() for ln in str(exc).strip().splitlines() if ln.strip()]
                ours = [ln for ln in lines if "SweepJobsFailed" in ln]
                what = (ours[-1].split("SweepJobsFailed:", 1)[-1].strip() if ours else lines[-1] if lines else "")
                echo(f"task {h.job_id} ended with an error: {what[:300]} (log: {h.paths.stdout})")
    return out


def sweep_numerics(spec: SweepSpec) -> str:
    """The one numeric mode of a sweep's jobs (benchmark.numerics), which their workers inherit."""
    modes = {numerics.mode_from_sets(sets) or numerics.DEFAULT for sets in spec.variants.values()}
    if len(modes) > 1:
        raise SweepError(f"{spec.path or spec.name}: the variants ask for {' and '.join(sorted(modes))} numerics; a "
                         "sweep computes in one mode (its rows are compared): split it into one sweep per mode")
    return modes.pop()


def _freeze_spec(spec: SweepSpec) -> None:
    """A copy of the spec as submitted, for the record (the jobs carry their own definitions)."""
    from benchmark.io import atomic_write_text

    if spec.path is not None and Path(spec.path).is_file():
        stamp = time.strftime("%Y%m%d-%H%M%S")
        atomic_write_text(spec.state_dir / "specs" / f"{stamp}-{os.getpid()}.toml", Path(spec.path).read_text())


def _restore(spec: SweepSpec, jobs: list[SweepJob], before: dict) -> None:
    from benchmark.io import atomic_write_json

    for job in jobs:
        p = state_path(spec.target, job)
        with state_lock(spec.target, job):
            if before[job.id] is None:
                p.unlink(missing_ok=True)
            else:
                atomic_write_json(p, before[job.id])


def results_table(spec: SweepSpec) -> str:
    """Official mIoU of the finished jobs, mean ± std over sequences and seeds, as a table of
    method x variant rows and dataset columns (rendered from the results files)."""
    import pandas as pd

    from benchmark.results import load_results

    rows = []
    for job, st in status(spec, ask_scheduler=False):
        for r in st.get("results", []) if st["state"] == "done" and not st.get("earlier_spec") else []:
            rec = load_results(r)
            rows.append({"method": job.method, "variant": job.variant, "dataset": job.dataset,
                         "miou": rec["metrics"]["official"]["miou"]})
    if not rows:
        return "no finished runs yet"
    df = pd.DataFrame(rows)
    agg = df.groupby(["method", "variant", "dataset"])["miou"].agg(["mean", "std", "count"]).reset_index()
    agg["cell"] = [f"{m:.4f} ± {0.0 if pd.isna(s) else s:.4f} (n={n})" for m, s, n in zip(agg["mean"], agg["std"], agg["count"])]
    return agg.pivot(index=["method", "variant"], columns="dataset", values="cell").fillna("").to_string()
