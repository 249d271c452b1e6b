"""Sweeps: methods x datasets x sequences x variants x seeds as jobs, on this machine or a
SLURM cluster through submitit, sharing one stage cache.

A spec (TOML) names what to run; each job is one ``trase-bench run`` of one method on one
sequence with one variant's ``--set`` overrides and one run seed. Jobs write their state to
``<out>/.sweep/<name>/jobs/<id>.json`` (running, done, failed with the one-line error and the
log's path), so ``sweep-status`` answers without the scheduler and a rerun submits only what is
not done. Jobs that share a scene share its stages through the cache, whose per-stage locks
(``benchmark.stage_lock``) let concurrent workers compute each stage once.

Runs land where ``run`` puts them (``<out>/<method>/<dataset>/<sequence>/<name>``): the
variant ``main`` (no overrides) is each method's main run, any other variant is a named run
(its name is the variant's), so ``leaderboard`` and ``runs`` read a sweep like any results tree.
"""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import sys
import time
from pathlib import Path

from benchmark.errors import UserError
from benchmark.stage_lock import known_dead

MAIN = "main"
EXECUTORS = ("local", "slurm")
SLURM_KEYS = {"partition": str, "gpus_per_node": int, "cpus_per_task": int, "mem_gb": int, "timeout_min": int,
              "array_parallelism": int, "account": str, "qos": str, "constraint": str, "additional": dict}


class SweepError(UserError):
    pass


@dataclasses.dataclass(frozen=True)
class SweepJob:
    index: int
    method: str
    dataset: str
    sequence: str | None  # None: the built-in synthetic scene
    variant: str
    overrides: tuple[str, ...]
    seed: int

    @property
    def id(self) -> str:
        seq = self.sequence or "synthetic"
        return f"{self.index:04d}-{self.method}-{self.dataset}-{seq}-{self.variant}-s{self.seed}"

    def label(self) -> str:
        return f"{self.method} {self.dataset}/{self.sequence or 'synthetic'} {self.variant} seed {self.seed}"


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
    def state_dir(self) -> Path:
        return self.out / ".sweep" / self.name

    @property
    def cache_root(self) -> Path:
        return self.cache or self.out / ".cache"

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
                            out.append(SweepJob(len(out), method, dataset, seq, variant, tuple(overrides), seed))
        return out

    def run_options(self, job: SweepJob):
        from benchmark.runner import RunOptions

        return RunOptions(method=job.method, dataset=job.dataset, sequences=[job.sequence] if job.sequence else None,
                          data_root=self.data_root, out_dir=self.out, cache_dir=self.cache,
                          overrides=[*job.overrides, f"seed={job.seed}"], progress=False,
                          name=None if job.variant == MAIN else job.variant, keep_existing=True)


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
def state_path(spec: SweepSpec, job: SweepJob) -> Path:
    return spec.state_dir / "jobs" / f"{job.id}.json"


def write_state(spec: SweepSpec, job: SweepJob, **fields) -> None:
    from benchmark.io import atomic_write_json

    atomic_write_json(state_path(spec, job), {"job": job.id, "label": job.label(), "time": time.time(), **fields})


def read_state(spec: SweepSpec, job: SweepJob) -> dict:
    """The job's state: done / running / failed / died / pending (with what the worker wrote)."""
    p = state_path(spec, job)
    try:
        st = json.loads(p.read_text())
    except FileNotFoundError:
        return {"state": "pending"}
    except (OSError, ValueError):
        return {"state": "pending", "note": f"{p}: unreadable state"}
    if st.get("state") == "running" and known_dead(st.get("host"), st.get("pid")):
        st["state"] = "died"
        st.setdefault("error", "the worker stopped without a word (killed?)")
    if st.get("state") == "done" and not all(Path(r).is_file() for r in st.get("results", [])):
        st["state"] = "pending"
        st["note"] = "its results are gone"
    return st


def run_job(spec: SweepSpec, job: SweepJob, log: str | None = None, task_id: str | None = None) -> list[str]:
    """Run one job here and record its state (with the scheduler's task id when run by one);
    returns its results.json paths."""
    from benchmark.errors import is_user_error
    from benchmark.runner import run

    write_state(spec, job, state="running", host=socket.gethostname(), pid=os.getpid(), started=time.time(), log=log,
                task=task_id)
    print(f"[{time.strftime('%H:%M:%S')}] job {job.id}: {job.label()}", flush=True)
    t0 = time.time()
    try:
        paths = [str(p) for p in run(spec.run_options(job))]
    except Exception as exc:
        line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        error = line if is_user_error(exc) else f"{type(exc).__name__}: {line}"
        write_state(spec, job, state="failed", error=error, log=log, seconds=time.time() - t0)
        print(f"[{time.strftime('%H:%M:%S')}] job {job.id} failed: {error}", flush=True)
        raise
    write_state(spec, job, state="done", results=paths, log=log, seconds=time.time() - t0)
    print(f"[{time.strftime('%H:%M:%S')}] job {job.id} done in {time.time() - t0:.0f}s: {', '.join(paths)}", flush=True)
    return paths


class SweepTask:
    """What a submitit job runs: its share of the sweep's jobs, in order. Checkpointable: on
    preemption SLURM requeues it, and the stage cache makes the rerun resume."""

    def __init__(self, spec_path: str, overrides: dict, job_ids: list[str]) -> None:
        self.spec_path, self.overrides, self.job_ids = spec_path, overrides, job_ids

    def __call__(self) -> dict:
        spec = load_spec(self.spec_path, self.overrides)
        by_id = {j.id: j for j in spec.jobs()}
        log, task_id = None, None
        try:
            import submitit

            env = submitit.JobEnvironment()
            log, task_id = str(env.paths.stdout), str(env.job_id)
        except RuntimeError:  # not inside a submitit job (tests call it directly)
            pass
        done, failed = [], []
        for jid in self.job_ids:
            job = by_id.get(jid)
            if job is None:
                failed.append(jid)
                continue
            if read_state(spec, job)["state"] == "done":
                done.append(jid)
                continue
            try:
                run_job(spec, job, log, task_id)
                done.append(jid)
            except Exception:  # noqa: BLE001 - recorded in the job's state; the next job runs
                failed.append(jid)
        return {"done": done, "failed": failed}

    def checkpoint(self, *args, **kwargs):
        import submitit

        return submitit.helpers.DelayedSubmission(self)


# -- submission ---------------------------------------------------------------------------
def pending_jobs(spec: SweepSpec) -> list[SweepJob]:
    """The jobs not done (a rerun submits only these)."""
    return [j for j in spec.jobs() if read_state(spec, j)["state"] != "done"]


def slurm_parameters(spec: SweepSpec) -> dict:
    """submitit's ``AutoExecutor.update_parameters`` arguments for the spec's [slurm] table."""
    s = spec.slurm
    extra = {k: s[k] for k in ("account", "qos", "constraint") if k in s} | dict(s.get("additional", {}))
    p = {"name": f"trase-{spec.name}", "timeout_min": s.get("timeout_min", 60), "slurm_partition": s.get("partition"),
         "gpus_per_node": s.get("gpus_per_node", 0), "cpus_per_task": s.get("cpus_per_task", 4),
         "mem_gb": s.get("mem_gb", 16), "slurm_array_parallelism": s.get("array_parallelism", 16),
         "slurm_additional_parameters": extra or None}
    return {k: v for k, v in p.items() if v is not None}


def sbatch_script(spec: SweepSpec, n_tasks: int) -> str:
    """The sbatch file submitit writes for the spec's job array of ``n_tasks`` (one task per
    job), made here without a cluster (submitit's own writer, fed the same parameters)."""
    from submitit.slurm.slurm import _make_sbatch_string  # the writer SlurmExecutor submits with

    p = slurm_parameters(spec)
    native = {"job_name": p["name"], "time": p["timeout_min"], "partition": p.get("slurm_partition"),
              "gpus_per_node": p["gpus_per_node"], "cpus_per_task": p["cpus_per_task"], "mem": f"{p['mem_gb']}GB",
              "array_parallelism": p["slurm_array_parallelism"],
              "additional_parameters": p.get("slurm_additional_parameters")}
    command = f"{sys.executable} -u -m submitit.core._submit {spec.state_dir / 'logs'}"
    return _make_sbatch_string(command=command, folder=spec.state_dir / "logs" / "%j", map_count=n_tasks,
                               **{k: v for k, v in native.items() if v is not None})


def submit(spec: SweepSpec, wait: bool = True, echo=print) -> dict:
    """Submit the pending jobs: ``local``, ``workers`` processes on this machine (submitit's
    local executor), each running its share in order; ``slurm``, one array task per job."""
    import submitit

    jobs = pending_jobs(spec)
    if not jobs:
        return {"submitted": 0, "tasks": 0}
    spec_path = str(spec.path.resolve())
    cli = {"kind": spec.executor, "workers": spec.workers, "slurm": spec.slurm}
    logs = spec.state_dir / "logs"
    if spec.executor == "local":
        ex = submitit.AutoExecutor(folder=logs, cluster="local")
        ex.update_parameters(timeout_min=int(spec.slurm.get("timeout_min", 24 * 60)))
        n = min(spec.workers, len(jobs))
        shares = [[j.id for j in jobs[i::n]] for i in range(n)]
    else:
        ex = submitit.AutoExecutor(folder=logs, cluster="slurm")
        ex.update_parameters(**slurm_parameters(spec))
        shares = [[j.id] for j in jobs]
    tasks = [SweepTask(spec_path, cli, share) for share in shares]
    for job in jobs:  # before submitting: a worker that starts at once overwrites it with running
        write_state(spec, job, state="submitted", executor=spec.executor)
    with ex.batch():
        handles = [ex.submit(t) for t in tasks]
    echo(f"submitted {len(jobs)} job(s) as {len(handles)} {spec.executor} task(s); logs in {logs}")
    out = {"submitted": len(jobs), "tasks": len(handles), "scheduler_ids": [str(h.job_id) for h in handles]}
    if wait:
        for h in handles:
            try:
                h.result()
            except Exception as exc:  # noqa: BLE001 - each job's own state says what failed
                echo(f"task {h.job_id} ended with an error: {str(exc).strip().splitlines()[-1][:200]}")
    return out


def status(spec: SweepSpec) -> list[tuple[SweepJob, dict]]:
    return [(j, read_state(spec, j)) for j in spec.jobs()]


def results_table(spec: SweepSpec) -> str:
    """Official mIoU of the finished jobs, mean ± std over sequences and seeds, as a table of
    method x variant rows and dataset columns (rendered from the results files)."""
    import pandas as pd

    from benchmark.results import load_results

    rows = []
    for job, st in status(spec):
        for r in st.get("results", []) if st["state"] == "done" else []:
            rec = load_results(r)
            rows.append({"method": job.method, "variant": job.variant, "dataset": job.dataset,
                         "miou": rec["metrics"]["official"]["miou"]})
    if not rows:
        return "no finished runs yet"
    df = pd.DataFrame(rows)
    agg = df.groupby(["method", "variant", "dataset"])["miou"].agg(["mean", "std", "count"]).reset_index()
    agg["cell"] = [f"{m:.4f} ± {0.0 if pd.isna(s) else s:.4f} (n={n})" for m, s, n in zip(agg["mean"], agg["std"], agg["count"])]
    return agg.pivot(index=["method", "variant"], columns="dataset", values="cell").fillna("").to_string()


__all__ = ["MAIN", "SweepError", "SweepJob", "SweepSpec", "SweepTask", "load_spec", "pending_jobs", "read_state",
           "results_table", "run_job", "sbatch_script", "slurm_parameters", "status", "submit"]
