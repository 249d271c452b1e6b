"""Sweeps: methods x datasets x sequences x variants x seeds as jobs, on this machine or a
SLURM cluster through submitit, sharing one stage cache.

A spec (TOML) names what to run; each job is one ``trase-bench run`` of one method on one
sequence with one variant's ``--set`` overrides and one run seed. A job's id comes from what it
runs (method, dataset, sequence, variant and its overrides, seed), so editing the spec never
renames a job. Submission freezes each job: its state file ``<out>/.sweep/<name>/jobs/<id>.json``
holds its definition and where its runs go, and the task a worker runs carries the same, never
the live TOML. Workers write their state there (running, done, failed with the one-line error
and the log's path); ``status`` reconciles it with the scheduler's view (queued, running,
requeued, cancelled, timed out: ``benchmark.scheduler``), and a rerun submits only jobs that are
neither done nor in flight. A task whose job failed exits non-zero, so the scheduler sees it.
Jobs that share a scene share its stages through the cache, whose per-stage locks
(``benchmark.stage_lock``) let concurrent workers compute each stage once.

Runs land where ``run`` puts them (``<out>/<method>/<dataset>/<sequence>/<name>``): the
variant ``main`` (no overrides) is each method's main run, any other variant is a named run
(its name is the variant's), so ``leaderboard`` and ``runs`` read a sweep like any results tree.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import io
import json
import os
import socket
import sys
import time
from pathlib import Path

from benchmark import numerics
from benchmark.errors import UserError
from benchmark.stage_lock import known_dead

MAIN = "main"
EXECUTORS = ("local", "slurm")
IN_FLIGHT = ("queued", "running", "requeued")  # a rerun leaves these alone
DEFAULT_CPUS, DEFAULT_MEM_GB = 4, 16  # per job, each capped at the partition's largest node when not given
SLURM_KEYS = {"partition": str, "gpus_per_node": int, "cpus_per_task": int, "mem_gb": int, "timeout_min": int,
              "array_parallelism": int, "account": str, "qos": str, "constraint": str, "additional": dict}


class SweepError(UserError):
    pass


@dataclasses.dataclass(frozen=True)
class SweepJob:
    method: str
    dataset: str
    sequence: str | None  # None: the built-in synthetic scene
    variant: str
    overrides: tuple[str, ...]
    seed: int

    @property
    def id(self) -> str:
        """Readable and from content: the same job keeps its id whatever else the spec holds."""
        seq = self.sequence or "synthetic"
        what = json.dumps([self.method, self.dataset, seq, self.variant, list(self.overrides), self.seed])
        return f"{self.method}-{self.dataset}-{seq}-{self.variant}-s{self.seed}-{hashlib.sha1(what.encode()).hexdigest()[:8]}"

    def label(self) -> str:
        return f"{self.method} {self.dataset}/{self.sequence or 'synthetic'} {self.variant} seed {self.seed}"

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "overrides": list(self.overrides)}

    @classmethod
    def from_dict(cls, d: dict) -> SweepJob:
        return cls(d["method"], d["dataset"], d["sequence"], d["variant"], tuple(d["overrides"]), int(d["seed"]))


@dataclasses.dataclass(frozen=True)
class SweepTarget:
    """Where a sweep's jobs put their runs, cache and states: what a submitted job is frozen with."""

    name: str
    out: Path
    data_root: Path | None = None
    cache: Path | None = None

    @property
    def state_dir(self) -> Path:
        return self.out / ".sweep" / self.name

    @property
    def cache_root(self) -> Path:
        return self.cache or self.out / ".cache"

    def run_options(self, job: SweepJob):
        from benchmark.runner import RunOptions

        return RunOptions(method=job.method, dataset=job.dataset, sequences=[job.sequence] if job.sequence else None,
                          data_root=self.data_root, out_dir=self.out, cache_dir=self.cache,
                          overrides=[*job.overrides, f"seed={job.seed}"], progress=False,
                          name=None if job.variant == MAIN else job.variant, keep_existing=True)

    def to_dict(self) -> dict:
        return {k: None if v is None else str(v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> SweepTarget:
        path = lambda v: None if v is None else Path(v)
        return cls(d["name"], Path(d["out"]), path(d.get("data_root")), path(d.get("cache")))


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    name: str
    out: Path
    methods: tuple[str, ...]
    datasets: tuple[str, ...]
    sequences: dict  # dataset -> [sequence]; missing: what `run` would choose
    variants: dict  # name -> [override]
    seeds: tuple[int, ...]
    data_root: Path | None = None
    cache: Path | None = None
    executor: str = "local"
    workers: int = 1  # local executor: processes in parallel
    slurm: dict = dataclasses.field(default_factory=dict)
    path: Path | None = None

    @property
    def target(self) -> SweepTarget:
        return SweepTarget(self.name, self.out, self.data_root, self.cache)

    @property
    def state_dir(self) -> Path:
        return self.target.state_dir

    @property
    def cache_root(self) -> Path:
        return self.target.cache_root

    def jobs(self) -> list[SweepJob]:
        from benchmark.datasets import get_dataset
        from benchmark.runner import default_sequences

        out = []
        for dataset in self.datasets:
            seqs = self.sequences.get(dataset) or default_sequences(get_dataset(dataset), self.data_root)
            for method in self.methods:
                for seq in seqs:
                    for variant, overrides in self.variants.items():
                        for seed in self.seeds:
                            out.append(SweepJob(method, dataset, seq, variant, tuple(overrides), seed))
        return out

    def run_options(self, job: SweepJob):
        return self.target.run_options(job)


def load_spec(path: Path | str, overrides: dict | None = None) -> SweepSpec:
    """Read and check a sweep spec; ``overrides`` (from the command line) replace its
    executor settings: executor, workers and slurm.* keys."""
    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib

    from benchmark.datasets import DATASETS
    from benchmark.methods import METHODS

    path = Path(path)
    if not path.is_file():
        raise SweepError(f"{path}: sweep spec not found")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SweepError(f"{path}: malformed TOML ({exc})") from None
    where = lambda key: f"{path}: {key}"
    known = {"name", "out", "data_root", "cache", "methods", "datasets", "sequences", "variants", "seeds",
             "executor", "slurm"}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise SweepError(where(f"unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})"))

    def strings(key: str, allowed=None) -> tuple[str, ...]:
        v = doc.get(key)
        if not isinstance(v, list) or not v or not all(isinstance(x, str) for x in v):
            raise SweepError(where(f"{key} must be a non-empty list of names"))
        bad = [x for x in v if allowed is not None and x not in allowed]
        if bad:
            raise SweepError(where(f"{key}: unknown {bad[0]!r} (known: {', '.join(sorted(allowed))})"))
        return tuple(v)

    methods = strings("methods", set(METHODS.names()))
    datasets = strings("datasets", set(DATASETS))
    seeds = doc.get("seeds", [0])
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and s >= 0 for s in seeds):
        raise SweepError(where("seeds must be a non-empty list of whole numbers >= 0"))
    variants = doc.get("variants", {MAIN: []})
    if not isinstance(variants, dict) or not variants or not all(
            isinstance(v, list) and all(isinstance(o, str) and "=" in o for o in v) for v in variants.values()):
        raise SweepError(where("variants must map names to lists of KEY=VALUE overrides"))
    sequences = doc.get("sequences", {})
    if not isinstance(sequences, dict) or not all(isinstance(v, list) for v in sequences.values()):
        raise SweepError(where("sequences must map datasets to lists of sequence names"))
    ex = {**doc.get("executor", {}), **{k: v for k, v in (overrides or {}).items() if k in ("kind", "workers")}}
    kind = ex.get("kind", "local")
    if kind not in EXECUTORS:
        raise SweepError(where(f"executor.kind {kind!r}: choose {' or '.join(EXECUTORS)}"))
    workers = ex.get("workers", 1)
    if not isinstance(workers, int) or workers < 1:
        raise SweepError(where("executor.workers must be a whole number >= 1"))
    slurm = {**doc.get("slurm", {}), **(overrides or {}).get("slurm", {})}
    for k, v in slurm.items():
        if k not in SLURM_KEYS:
            raise SweepError(where(f"slurm.{k}: unknown (known: {', '.join(SLURM_KEYS)})"))
        if not isinstance(v, SLURM_KEYS[k]) or isinstance(v, bool):
            raise SweepError(where(f"slurm.{k} = {v!r}: expected {SLURM_KEYS[k].__name__}"))
    base = path.parent
    rel = lambda v: None if v is None else (Path(v) if Path(v).is_absolute() else base / v)
    name = str(doc.get("name", path.stem))
    data_root = rel(doc.get("data_root")) or (Path(os.environ["TRASE_DATA"]) if os.environ.get("TRASE_DATA") else None)
    return SweepSpec(name=name, out=rel(doc.get("out", f"sweeps/{name}")), methods=methods, datasets=datasets,
                     sequences=sequences, variants={k: list(v) for k, v in variants.items()},
                     seeds=tuple(seeds), data_root=data_root, cache=rel(doc.get("cache")), executor=kind,
                     workers=workers, slurm=slurm, path=path)


# -- job state ----------------------------------------------------------------------------
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


def _read_file(target, job: SweepJob) -> dict | None:
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
    st = _read_file(target, job) if written is _UNREAD else written
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


# -- submission ---------------------------------------------------------------------------
def status(spec: SweepSpec, ask_scheduler: bool = True, strict: bool = True) -> list[tuple[SweepJob, dict]]:
    """Every job of the spec with its reconciled state, then the jobs of earlier versions of the
    spec that are still in flight or finished (their state files), marked ``earlier_spec``.
    ``strict``: SLURM not answering is an error (what submission needs: it must not queue a job
    twice); otherwise the states are the workers' own, with a note saying why."""
    jobs = spec.jobs()
    written = {j.id: _read_file(spec.target, j) for j in jobs}
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
    before = {j.id: _read_file(spec.target, j) for j in jobs}  # read now: a worker may have written since status
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
                st = _read_file(spec.target, job) or {}
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


__all__ = ["IN_FLIGHT", "MAIN", "SweepError", "SweepJob", "SweepJobsFailed", "SweepSpec", "SweepTarget", "SweepTask",
           "load_spec", "pending_jobs", "read_state", "resolve_resources", "results_table", "run_job", "sbatch_script",
           "slurm_parameters", "status", "submit"]
