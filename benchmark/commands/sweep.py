"""``trase-bench sweep SPEC`` and ``trase-bench sweep-status SPEC``."""

from __future__ import annotations

import click


def _overrides(executor, workers, partition, gpus, time_min, mem, array_parallelism, cpus=None) -> dict:
    slurm = {k: v for k, v in {"partition": partition, "gpus_per_node": gpus, "timeout_min": time_min,
                               "mem_gb": mem, "array_parallelism": array_parallelism,
                               "cpus_per_task": cpus}.items() if v is not None}
    out = {"slurm": slurm}
    if executor:
        out["kind"] = executor
    if workers:
        out["workers"] = workers
    return out


@click.command(name="sweep")
@click.argument("spec_path", metavar="SPEC", type=click.Path(dir_okay=False))
@click.option("--dry-run", is_flag=True, help="Print the jobs and which stages each would reuse; run nothing.")
@click.option("--executor", type=click.Choice(["local", "slurm"]), default=None, help="Overrides the spec's.")
@click.option("--workers", type=click.IntRange(min=1), default=None, help="local: processes in parallel.")
@click.option("--partition", default=None, help="slurm: partition.")
@click.option("--gpus", type=click.IntRange(min=0), default=None, help="slurm: GPUs per job.")
@click.option("--cpus-per-task", "cpus", type=click.IntRange(min=1), default=None,
              help="slurm: CPU cores per job (default 4, capped at the partition's largest node).")
@click.option("--time", "time_min", type=click.IntRange(min=1), default=None, help="slurm: minutes per job.")
@click.option("--mem", type=click.IntRange(min=1), default=None,
              help="slurm: GB of memory per job (default 16, capped at the partition's largest node).")
@click.option("--array-parallelism", type=int, default=None, help="slurm: array tasks running at once.")
@click.option("--wait/--no-wait", default=None, help="Wait for the jobs (default: local yes, slurm no).")
def sweep(spec_path, dry_run, executor, workers, partition, gpus, cpus, time_min, mem, array_parallelism,
          wait) -> None:
    """Run a sweep (methods x datasets x sequences x variants x seeds) from a TOML spec;
    a rerun runs only what is not done."""
    import time

    from benchmark.sweep import IN_FLIGHT, load_spec, pending_jobs, status, submit

    spec = load_spec(spec_path, _overrides(executor, workers, partition, gpus, time_min, mem, array_parallelism,
                                           cpus))
    if not any(o.startswith(("preset=", "geometry.preset=")) for v in spec.variants.values() for o in v):
        click.echo("note: no variant pins the preset (preset=...); 'auto' resolves on each worker (paper where torch "
                   "sees a GPU, cpu elsewhere), so jobs on mixed nodes would run different presets", err=True)
    if dry_run:
        _dry_run(spec)
        return
    t0 = time.time()
    states = status(spec)
    todo = pending_jobs(spec, states)
    flying = sum(st["state"] in IN_FLIGHT for _, st in states if not st.get("earlier_spec"))
    click.echo(f"sweep {spec.name}: {len(spec.jobs())} jobs, {len(todo)} to run, {flying} in flight "
               f"({spec.executor}); runs {spec.out}")
    res = submit(spec, wait=(spec.executor == "local") if wait is None else wait, echo=click.echo, states=states)
    if res["submitted"] and (wait or (wait is None and spec.executor == "local")):
        click.echo(f"wall time {time.time() - t0:.1f}s")
        _summary(spec)
    click.echo(f"status: trase-bench sweep-status {spec_path}")


def _dry_run(spec) -> None:
    from benchmark.errors import is_user_error
    from benchmark.runner import plan_sequence
    from benchmark.sweep import read_state

    rows, planned = [], set()  # (stage, key) an earlier job of the sweep computes
    for job in spec.jobs():
        st = read_state(spec, job)["state"]  # as the workers wrote it (the scheduler is not asked)
        try:
            plan = plan_sequence(spec.run_options(job), job.sequence)
            marks = ["=" if done else "^" if (stage, key) in planned else "+" for stage, key, done in plan]
            planned |= {(stage, key) for stage, key, done in plan if not done}
            reuse = " ".join(f"{stage}{m}" for (stage, _, _), m in zip(plan, marks))
        except Exception as exc:
            if not is_user_error(exc):
                raise
            reuse = f"(cannot plan: {str(exc).splitlines()[0]})"
        rows.append(f"{job.id:<66} {st:<9} {reuse}")
    click.echo(f"{'job':<66} state     stages "
               "(= in the cache, ^ computed by an earlier job of this sweep, + computed by this job)")
    for r in rows:
        click.echo(r)
    if spec.executor == "slurm":
        from benchmark.scheduler import SchedulerError
        from benchmark.sweep import resolve_resources, sbatch_script, slurm_parameters

        try:
            spec = resolve_resources(spec, echo=click.echo)
        except SchedulerError as exc:  # a dry run away from the cluster still shows the script
            click.echo(f"note: the request was not checked against the partition: {exc}")
        click.echo(f"\nsubmitit parameters: {slurm_parameters(spec)}")
        click.echo(sbatch_script(spec, len(spec.jobs())))


def _summary(spec) -> None:
    from benchmark.results import load_results
    from benchmark.sweep import status

    states: dict[str, int] = {}
    stages = {"computed": 0, "reused": 0}
    for _, st in status(spec):
        states[st["state"]] = states.get(st["state"], 0) + 1
        for r in st.get("results", []):
            for s in load_results(r).get("stages", {}).values():
                stages["reused" if s.get("skipped") else "computed"] += 1
    click.echo(", ".join(f"{n} {k}" for k, n in sorted(states.items())) +
               f"; stages computed {stages['computed']}, reused {stages['reused']}")


@click.command(name="sweep-status")
@click.argument("spec_path", metavar="SPEC", type=click.Path(dir_okay=False))
@click.option("--table", is_flag=True, help="Also the mIoU table of the finished runs (method x variant x dataset).")
def sweep_status(spec_path, table) -> None:
    """Each job's state (done, running, queued, requeued, failed, cancelled, timed out, died, lost,
    pending), reconciled with SLURM's view where jobs went to SLURM, with errors and logs."""
    from benchmark.sweep import load_spec, status

    spec = load_spec(spec_path)
    counts: dict[str, int] = {}
    notes = set()
    for job, st in status(spec, strict=False):
        if st.get("note"):
            notes.add(st["note"])
        state = st["state"]
        counts[state] = counts.get(state, 0) + 1
        line = f"{job.id:<66} {state}"
        if state in ("failed", "died", "lost", "cancelled", "timed out"):
            line += f"  {st.get('error', '')}".rstrip() + f"  log: {st.get('log') or 'none'}"
        elif state == "done":
            line += f"  {st.get('seconds', 0):.0f}s"
        elif state == "running":
            task = f", {st['scheduler_id']}" if st.get("scheduler_id") else ""
            where = f"on {st.get('host')} (pid {st.get('pid')}{task})" if st.get("started") else "starting"
            line += f"  {where}, log {st.get('log') or 'none'}"
        elif state in ("queued", "requeued"):
            line += f"  {st.get('executor')} {st.get('scheduler_id') or ''}".rstrip()
        if st.get("scheduler"):
            line += f"  [{st['scheduler']}]"
        if st.get("earlier_spec"):
            line += "  (not in the spec now: submitted by an earlier version)"
        click.echo(line)
    click.echo(", ".join(f"{n} {k}" for k, n in sorted(counts.items())))
    for n in sorted(notes):
        click.echo(f"note: {n}")
    if table:
        from benchmark.sweep import results_table

        click.echo(results_table(spec))
    click.echo(f"leaderboards: trase-bench leaderboard --runs {spec.out}   (main runs; the variants other "
               f"than main are named runs: add --kind run)")
