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

from benchmark.sweep.spec import MAIN, SweepError, SweepJob, SweepSpec, SweepTarget, load_spec
from benchmark.sweep.state import (
    IN_FLIGHT,
    SweepJobsFailed,
    SweepTask,
    read_state,
    run_job,
    state_path,
    write_state,
)
from benchmark.sweep.submission import (
    idle_threads_sleep,
    pending_jobs,
    resolve_resources,
    results_table,
    sbatch_script,
    slurm_parameters,
    status,
    submit,
    sweep_numerics,
)

__all__ = ["IN_FLIGHT", "MAIN", "SweepError", "SweepJob", "SweepJobsFailed", "SweepSpec", "SweepTarget", "SweepTask",
           "idle_threads_sleep", "load_spec", "pending_jobs", "read_state", "resolve_resources", "results_table",
           "run_job", "sbatch_script", "slurm_parameters", "state_path", "status", "submit", "sweep_numerics",
           "write_state"]
