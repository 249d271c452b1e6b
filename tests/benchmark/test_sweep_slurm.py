"""Sweeps against a real one-node SLURM (tests/benchmark/slurm_cluster.py): resubmission while
jobs are in flight, ids stable under edits of the spec, failures SLURM sees, a spec edited
while its jobs wait, rejected submissions, cancel and requeue, and resuming inside the feature
stage after a requeue. Skipped with the reason where the daemons cannot start (not root, not
installed)."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest

from benchmark.cli import main
from benchmark.sweep import load_spec, status

pytestmark = pytest.mark.slow

FAST = ["preset=cpu", "geometry.source=ground-truth", "method.features.iterations=10", "method.features.n_pixels=300",
        "prompts.click_sets=1"]


def _toml(tmp_path: Path, variants: dict, seeds=(0,), slurm: str = "", out: str = "out", kind: str = "slurm",
          name: str = "s.toml") -> Path:
    lines = [f'name = "{Path(name).stem}"', f'out = "{out}"', 'methods = ["trase"]', 'datasets = ["hypernerf"]',
             f"seeds = {list(seeds)}", "[sequences]", 'hypernerf = ["synthetic-tiny"]', "[variants]"]
    lines += [f"{v} = {json.dumps(FAST + extra)}" for v, extra in variants.items()]
    lines += ["[executor]", f'kind = "{kind}"', "[slurm]", "timeout_min = 30", slurm]
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def _states(path: Path) -> dict[str, dict]:
    return {job.id: st for job, st in status(load_spec(path))}


def _wait(path: Path, done, timeout: float = 900.0, what: str = "") -> dict[str, dict]:
    deadline = time.time() + timeout
    while True:
        states = _states(path)
        if done(states):
            return states
        assert time.time() < deadline, f"timed out waiting for {what}: {[s['state'] for s in states.values()]}"
        time.sleep(1.0)


def _scontrol(slurm, job_id: str) -> dict:
    line = slurm.run("scontrol", "show", "job", "-o", job_id).splitlines()[0]
    return dict(re.findall(r"(\w+)=(\S*)", line))


def _ended(slurm, job_id: str, timeout: float = 60.0) -> dict:
    """SLURM's record of a job once it has ended (a worker writes its state before it exits)."""
    deadline = time.time() + timeout
    while (info := _scontrol(slurm, job_id))["JobState"] in ("RUNNING", "COMPLETING", "PENDING"):
        assert time.time() < deadline, info["JobState"]
        time.sleep(0.5)
    return info


def test_resubmitted_and_extended_while_running_each_job_runs_once_as_locally(slurm, tmp_path, capsys):
    path = _toml(tmp_path, {"a": [], "b": ["method.clustering.params.min_cluster_size=10"]}, seeds=(0, 1))
    assert main(["sweep", str(path), "--dry-run"]) == 0
    dry = capsys.readouterr().out
    (pattern,) = re.findall(r"#SBATCH --output=(\S+)", dry)
    assert main(["sweep", str(path), "--no-wait"]) == 0
    out = capsys.readouterr().out
    assert "4 to run, 0 in flight" in out and "submitted 4 job(s) as 4 slurm task(s)" in out
    assert "slurm.cpus_per_task not given: 2" in out or slurm.cpus >= 4  # capped at the node, not queued forever
    # submitted again while they wait or run: nothing is submitted twice
    assert main(["sweep", str(path), "--no-wait"]) == 0
    out = capsys.readouterr().out
    assert "0 to run, 4 in flight" in out and "not submitted again" in out and "submitted 4" not in out
    assert len(slurm.run("squeue", "-h", "-r", "-o", "%i").split()) <= 4
    # the dry run printed the log path the submission used
    first = _states(path)
    sid = next(iter(first.values()))["scheduler_id"]
    array, task = sid.split("_")
    assert pattern.replace("%A", array).replace("%a", task) == next(iter(first.values()))["log"]
    # a variant added afterwards: only its jobs run; the others keep their ids
    path.write_text(path.read_text().replace("[executor]", f"c = {json.dumps(FAST + ['method.filter_threshold=0.6'])}"
                                             "\n[executor]"))
    assert main(["sweep", str(path), "--no-wait"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"6 jobs, 2 to run, \d in flight", out), out
    states = _wait(path, lambda s: all(x["state"] == "done" for x in s.values()), what="the sweep")
    assert set(first) < set(states) and len(states) == 6
    for st in states.values():  # each job ran once: one start line in all the logs together
        assert _ended(slurm, st["scheduler_id"])["JobState"] == "COMPLETED"
    logs = "".join(p.read_text() for p in (load_spec(path).state_dir / "logs").glob("*_log.out"))
    for jid in states:
        assert logs.count(f"job {jid}: ") == 1, jid
    # the same spec on this machine: identical scores, job for job
    local = _toml(tmp_path, {}, kind="local", out="local", name="l.toml")
    local.write_text(path.read_text().replace('out = "out"', 'out = "local"').replace('kind = "slurm"', 'kind = "local"')
                     .replace('name = "s"', 'name = "l"'))
    assert main(["sweep", str(local)]) == 0
    here = _states(local)
    for jid, st in states.items():
        a = json.loads(Path(st["results"][0]).read_text())
        b = json.loads(Path(here[jid]["results"][0]).read_text())
        assert a["metrics"]["official"]["miou"] == b["metrics"]["official"]["miou"]
        assert a["checksums"] == b["checksums"]


def test_a_failing_job_is_failed_in_slurm_with_a_non_zero_exit_code(slurm, tmp_path, capsys):
    path = _toml(tmp_path, {"broken": ["method.features.dim=0"]}, slurm="cpus_per_task = 1")
    assert main(["sweep", str(path), "--no-wait"]) == 0
    states = _wait(path, lambda s: all(x["state"] == "failed" for x in s.values()), what="the failure")
    (st,) = states.values()
    assert "feature dim must be >= 1" in st["error"]
    info = _ended(slurm, st["scheduler_id"])
    assert info["JobState"] == "FAILED" and info["ExitCode"] != "0:0"
    capsys.readouterr()
    assert main(["sweep-status", str(path)]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    assert " failed " in line and "feature dim must be >= 1" in line and st["log"] in line


def test_a_spec_edited_while_its_jobs_wait_runs_what_was_submitted(slurm, tmp_path, capsys):
    path = _toml(tmp_path, {"a": []}, slurm="cpus_per_task = 1\n[slurm.additional]\nhold = true")
    assert main(["sweep", str(path), "--no-wait"]) == 0
    (old_id,) = _states(path)
    sid = _states(path)[old_id]["scheduler_id"]
    assert _states(path)[old_id]["state"] == "queued"
    # edited while held: another override (a new job id) and no hold
    path.write_text(path.read_text().replace("iterations=10", "iterations=12").replace("hold = true", ""))
    slurm.run("scontrol", "release", sid.split("_")[0])
    states = _wait(path, lambda s: s.get(old_id, {}).get("state") == "done", what="the frozen job")
    assert states[old_id]["earlier_spec"]
    rec = json.loads(Path(states[old_id]["results"][0]).read_text())
    assert rec["config"]["method"]["features"]["iterations"] == 10  # what was submitted, not the edit
    (new_id,) = [j for j in states if j != old_id]
    assert states[new_id]["state"] == "pending"
    assert main(["sweep-status", str(path)]) == 0
    assert "not in the spec now" in capsys.readouterr().out


def test_rejected_submissions_are_one_line_and_mark_nothing(slurm, tmp_path, capsys):
    path = _toml(tmp_path, {"a": []}, slurm="cpus_per_task = 1")
    jobs_dir = load_spec(path).state_dir / "jobs"
    for args, said in ((["--partition", "nosuch"], "partition 'nosuch' does not exist (sinfo knows: debug)"),
                       (["--cpus-per-task", "64"], "--cpus-per-task 64 (largest node: "),
                       (["--mem", "999"], "--mem 999 GB (largest node: ")):
        assert main(["sweep", str(path), "--no-wait", *args]) == 1
        err = capsys.readouterr().err.strip()
        assert said in err and len(err.splitlines()) == 1 and "Traceback" not in err, err
        assert not list(jobs_dir.glob("*.json"))
    # one sbatch itself refuses: its own words, and the states are put back
    bad = _toml(tmp_path, {"a": []}, slurm='cpus_per_task = 1\nconstraint = "nosuchfeature"', name="bad.toml")
    assert main(["sweep", str(bad), "--no-wait"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: sbatch refused the jobs:") and len(err.splitlines()) == 1, err
    assert not list((load_spec(bad).state_dir / "jobs").glob("*.json"))


def test_cancel_and_requeue_show_as_the_scheduler_sees_them_and_the_features_resume(slurm, tmp_path, monkeypatch):
    monkeypatch.setenv("TRASE_CHECKPOINT_SECONDS", "0.2")  # the jobs inherit it
    long = ["method.features.iterations=4000"]  # tens of seconds: the requeue lands inside the stage
    path = _toml(tmp_path, {"long": long, "next": ["method.features.lr=0.02"]},
                 slurm=f"cpus_per_task = {slurm.cpus}")  # one job at a time on this node
    assert main(["sweep", str(path), "--no-wait"]) == 0
    spec = load_spec(path)
    ids = {j.variant: j.id for j in spec.jobs()}
    _wait(path, lambda s: s[ids["long"]]["state"] == "running" and s[ids["next"]]["state"] == "queued",
          what="one running, one queued")
    cancelled = _states(path)[ids["next"]]["scheduler_id"]
    slurm.run("scancel", cancelled)
    _wait(path, lambda s: s[ids["next"]]["state"] == "cancelled", what="the cancel")
    deadline = time.time() + 600
    while not list(spec.cache_root.glob("features/*.partial/work/features_checkpoint.pt")):
        assert time.time() < deadline, "the feature stage never saved its state"
        time.sleep(0.1)
    running = _states(path)[ids["long"]]["scheduler_id"]
    slurm.run("scontrol", "requeuehold", running)
    st = _wait(path, lambda s: s[ids["long"]]["state"] == "requeued", what="the requeue")[ids["long"]]
    assert "PENDING" in st["scheduler"]
    slurm.run("scontrol", "release", running)
    st = _wait(path, lambda s: s[ids["long"]]["state"] == "done", what="the requeued job")[ids["long"]]
    rec = json.loads(Path(st["results"][0]).read_text())
    assert rec["stages"]["features"]["info"]["resumed_from_step"] > 0
    assert int(_scontrol(slurm, running)["Restarts"]) >= 1
    # a rerun submits the cancelled job again, not the finished one
    assert main(["sweep", str(path), "--no-wait"]) == 0
    assert _states(path)[ids["next"]]["state"] in ("queued", "running", "done")
    _wait(path, lambda s: s[ids["next"]]["state"] == "done", what="the resubmitted job")
