"""Sweeps: the spec, its jobs, the SLURM submission it makes, and local sweeps on tiny scenes
through submitit's local executor (shared stages computed once, a killed worker, reruns)."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from benchmark.cli import main
from benchmark.sweep import SweepError, load_spec, read_state, sbatch_script, slurm_parameters

FAST = ["geometry.source=ground-truth", "method.features.iterations=40", "method.features.n_pixels=400"]


def _spec(tmp_path: Path, body: str, name: str = "s.toml") -> Path:
    p = tmp_path / name
    p.write_text(body)
    return p


TINY = """
name = "tiny"
out = "out"
methods = ["trase", "cgc"]
datasets = ["hypernerf"]
[sequences]
hypernerf = ["synthetic-tiny"]
[variants]
fast = [{fast}]
[executor]
kind = "local"
workers = 2
""".replace("{fast}", ", ".join(f'"{o}"' for o in FAST))


def test_jobs_expand_the_spec_in_order(tmp_path):
    spec = load_spec(_spec(tmp_path, """
methods = ["trase", "cgc"]
datasets = ["hypernerf", "nerfds"]
seeds = [0, 1]
[sequences]
hypernerf = ["a", "b"]
nerfds = ["c"]
[variants]
main = []
fast = ["method.features.iterations=10"]
"""))
    jobs = spec.jobs()
    assert len(jobs) == 2 * (2 + 1) * 2 * 2 and len({j.id for j in jobs}) == len(jobs)
    assert jobs[0].id.startswith("trase-hypernerf-a-main-s0-") and jobs[-1].id.startswith("cgc-nerfds-c-fast-s1-")
    opts = spec.run_options(jobs[1])
    assert opts.overrides == ["seed=1"] and opts.name is None and opts.keep_existing  # main: the main run
    fast = spec.run_options(next(j for j in jobs if j.variant == "fast"))
    assert fast.name == "fast" and fast.overrides[0] == "method.features.iterations=10"
    assert spec.out == tmp_path / "sweeps" / "s" and spec.cache_root == spec.out / ".cache"


@pytest.mark.parametrize("body, message", [
    ("methods = [\n", "malformed TOML"),
    ('datasets = ["hypernerf"]', "methods must be a non-empty list"),
    ('methods = ["nope"]\ndatasets = ["hypernerf"]', "methods: unknown 'nope'"),
    ('methods = ["trase"]\ndatasets = ["kitti"]', "datasets: unknown 'kitti'"),
    ('methods = ["trase"]\ndatasets = ["hypernerf"]\nseeds = [-1]', "seeds must be"),
    ('methods = ["trase"]\ndatasets = ["hypernerf"]\nmethod = "x"', "unknown key 'method'"),
    ('methods = ["trase"]\ndatasets = ["hypernerf"]\n[variants]\na = ["no-equals"]', "KEY=VALUE"),
    ('methods = ["trase"]\ndatasets = ["hypernerf"]\n[executor]\nkind = "pbs"', "executor.kind 'pbs'"),
    ('methods = ["trase"]\ndatasets = ["hypernerf"]\n[slurm]\ngpus = 1', "slurm.gpus: unknown"),
    ('methods = ["trase"]\ndatasets = ["hypernerf"]\n[slurm]\nmem_gb = "32G"', "expected int"),
])
def test_bad_specs_are_one_line_naming_the_file(tmp_path, capsys, body, message):
    path = _spec(tmp_path, body)
    with pytest.raises(SweepError) as err:
        load_spec(path)
    assert str(err.value).startswith(str(path)) and message in str(err.value) and "\n" not in str(err.value)
    assert main(["sweep", str(path), "--dry-run"]) == 1
    assert message in capsys.readouterr().err
    assert main(["sweep", str(tmp_path / "none.toml")]) == 1 and "sweep spec not found" in capsys.readouterr().err


def test_the_slurm_submission_of_a_sample_spec(tmp_path):
    spec = load_spec(_spec(tmp_path, """
name = "table1"
methods = ["trase", "cgc"]
datasets = ["hypernerf", "nerfds"]
[executor]
kind = "slurm"
[slurm]
partition = "gpu"
gpus_per_node = 1
cpus_per_task = 8
mem_gb = 32
timeout_min = 120
array_parallelism = 6
account = "vision"
"""), {"slurm": {"timeout_min": 90}})  # the command line's --time wins
    assert slurm_parameters(spec) == {
        "name": "trase-table1", "timeout_min": 90, "slurm_partition": "gpu", "gpus_per_node": 1, "cpus_per_task": 8,
        "mem_gb": 32, "slurm_array_parallelism": 6, "slurm_additional_parameters": {"account": "vision"}}
    n = len(spec.jobs())
    script = sbatch_script(spec, n)
    for line in ("#SBATCH --partition=gpu", "#SBATCH --gpus-per-node=1", "#SBATCH --cpus-per-task=8",
                 "#SBATCH --mem=32GB", "#SBATCH --time=90", f"#SBATCH --array=0-{n - 1}%{min(6, n)}",  # submitit caps it at the array size
                 "#SBATCH --job-name=trase-table1", "#SBATCH --account=vision"):
        assert line in script, line
    assert str(spec.state_dir / "logs") in script


def test_local_workers_side_by_side_let_idle_threads_sleep(monkeypatch):
    from benchmark.sweep import idle_threads_sleep

    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    with idle_threads_sleep(False):
        assert "OMP_WAIT_POLICY" not in os.environ  # one worker: left as it is
    with idle_threads_sleep(True):
        assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    assert "OMP_WAIT_POLICY" not in os.environ
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")  # the user's choice is kept
    with idle_threads_sleep(True):
        assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"


@pytest.mark.slow
def test_a_local_sweep_computes_shared_stages_once_and_reruns_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    path = _spec(tmp_path, TINY)
    assert main(["sweep", str(path), "--dry-run"]) == 0
    plan = capsys.readouterr().out
    assert "masks+ geometry+" in plan and "masks^ geometry^" in plan  # the second job reuses the first's
    assert main(["sweep", str(path)]) == 0
    out = capsys.readouterr().out
    spec = load_spec(path)
    states = [read_state(spec, j) for j in spec.jobs()]
    assert [s["state"] for s in states] == ["done", "done"]
    assert [s["omp_wait_policy"] for s in states] == ["PASSIVE", "PASSIVE"]  # two workers: idle threads sleep
    assert "OMP_WAIT_POLICY" not in os.environ  # set for the workers only
    records = [json.loads(Path(s["results"][0]).read_text())["stages"] for s in states]
    for stage in ("masks", "geometry", "prompts", "ceiling"):  # the two workers share these
        assert sum(not r[stage]["skipped"] for r in records) == 1, stage
    assert "4 reused" in out or "reused 4" in out
    assert not list(spec.cache_root.glob("*/*.lock"))
    assert main(["sweep", str(path)]) == 0
    assert "0 to run" in capsys.readouterr().out
    assert main(["sweep-status", str(path), "--table"]) == 0
    status = capsys.readouterr().out
    assert "2 done" in status and "trase" in status and "cgc" in status


@pytest.mark.slow
def test_a_worker_killed_mid_stage_is_resumed_by_a_rerun(tmp_path, capsys):
    import subprocess
    import sys

    slow = TINY.replace('workers = 2', 'workers = 1').replace('methods = ["trase", "cgc"]', 'methods = ["trase"]')
    slow = slow.replace("iterations=40", "iterations=150")
    (tmp_path / "a").mkdir()
    path = _spec(tmp_path / "a", slow)
    spec = load_spec(path)
    (job,) = spec.jobs()
    p = subprocess.Popen([sys.executable, "-m", "benchmark.cli", "sweep", str(path)], cwd=tmp_path,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2]),
                              "TRASE_CHECKPOINT_SECONDS": "0.2"})
    try:
        deadline = time.time() + 300
        while not list(spec.cache_root.glob("features/*.partial/work/features_checkpoint.pt")):
            assert time.time() < deadline and p.poll() is None, "the features stage never saved its state"
            time.sleep(0.05)
        pid = json.loads((spec.state_dir / "jobs" / f"{job.id}.json").read_text())["pid"]
        os.kill(pid, signal.SIGKILL)
        p.wait(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert read_state(spec, job)["state"] == "died"
    assert not [d for d in spec.cache_root.glob("features/*") if d.is_dir() and not d.name.endswith(".partial")]
    assert main(["sweep", str(path)]) == 0
    assert read_state(spec, job)["state"] == "done"
    # an undisturbed sweep of the same spec elsewhere gives the same results
    (tmp_path / "b").mkdir()
    other = _spec(tmp_path / "b", slow)
    assert main(["sweep", str(other)]) == 0
    a = json.loads(Path(read_state(spec, job)["results"][0]).read_text())
    b_spec = load_spec(other)
    b = json.loads(Path(read_state(b_spec, b_spec.jobs()[0])["results"][0]).read_text())
    assert a["metrics"] == b["metrics"] and a["checksums"] == b["checksums"] and a["n_clusters"] == b["n_clusters"]
    assert a["stages"]["features"]["info"]["resumed_from_step"] > 0  # went on inside the stage
    assert b["stages"]["features"]["info"]["resumed_from_step"] == 0
    assert not list(spec.cache_root.glob("*/*.lock")) and not list(spec.cache_root.glob("*/*.partial"))


@pytest.mark.slow
def test_two_methods_on_the_five_formats(tmp_path, capsys):
    body = TINY.replace('datasets = ["hypernerf"]',
                        'datasets = ["nerfds", "hypernerf", "neu3d", "immersive", "technicolor"]')
    body = body.replace('[sequences]\nhypernerf = ["synthetic-tiny"]',
                        "[sequences]\n" + "\n".join(f'{d} = ["synthetic-tiny"]' for d in
                                                      ("nerfds", "hypernerf", "neu3d", "immersive", "technicolor")))
    path = _spec(tmp_path, body)
    assert main(["sweep", str(path)]) == 0
    spec = load_spec(path)
    states = [read_state(spec, j) for j in spec.jobs()]
    assert len(states) == 10 and all(s["state"] == "done" for s in states), [s.get("error") for s in states]
    assert main(["sweep-status", str(path), "--table"]) == 0
    table = capsys.readouterr().out
    assert all(d in table for d in ("nerfds", "hypernerf", "neu3d", "immersive", "technicolor"))


def test_a_job_that_ends_before_submit_returns_keeps_its_state(tmp_path, monkeypatch):
    """A local worker starts at once: the submitted state is written before the jobs are
    submitted, so a job that is already running or done is never set back to submitted."""
    import contextlib

    import submitit

    from benchmark import sweep as sw

    spec = load_spec(_spec(tmp_path, TINY))
    by_id = {j.id: j for j in spec.jobs()}

    class Handle:
        job_id = "42"

    class InstantExecutor:  # a worker that finishes its share before submit returns
        def __init__(self, folder, cluster):
            pass

        def update_parameters(self, **_):
            pass

        def batch(self):
            return contextlib.nullcontext()

        def submit(self, task):
            for jid in task.job_ids:
                sw.write_state(spec, by_id[jid], state="done", results=[])
            Handle.paths = type("P", (), {"stdout": tmp_path / "log"})
            return Handle()

    monkeypatch.setattr(submitit, "AutoExecutor", InstantExecutor)
    out = sw.submit(spec, wait=False, echo=lambda *_: None)
    assert out["submitted"] == len(by_id) == 2
    assert [read_state(spec, j)["state"] for j in by_id.values()] == ["done", "done"]


def test_a_submitter_and_a_worker_writing_one_state_at_once_both_succeed(tmp_path):
    # an atomic write sweeps away the temporaries of other writers of its path: without the
    # state lock one of two concurrent writers failed (a job "lost" before it started)
    import threading

    from benchmark.sweep import state_path, write_state

    spec = load_spec(_spec(tmp_path, TINY))
    job = spec.jobs()[0]
    errors = []

    def writer(state):
        try:
            for _ in range(100):
                write_state(spec.target, job, state=state)
        except Exception as exc:  # noqa: BLE001 - collected for the assertion
            errors.append(exc)

    threads = [threading.Thread(target=writer, args=(s,)) for s in ("submitted", "running")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert json.loads(state_path(spec.target, job).read_text())["state"] in ("submitted", "running")
    assert not list(state_path(spec.target, job).parent.glob("*.lock"))  # released


def test_a_sweep_computes_in_one_numeric_mode_its_workers_inherit(tmp_path):
    import dataclasses as dc

    from benchmark.sweep import SweepError, SweepSpec, sweep_numerics

    spec = SweepSpec("s", tmp_path, ("trase",), ("hypernerf",), {}, {"a": ("machine.numerics=native",), "b": ()}, (0,))
    with pytest.raises(SweepError, match="ask for native and portable numerics; a sweep computes in one mode"):
        sweep_numerics(spec)
    assert sweep_numerics(dc.replace(spec, variants={"a": ("machine.numerics=native",)})) == "native"
    assert sweep_numerics(dc.replace(spec, variants={"b": ("seed=1",)})) == "portable"
