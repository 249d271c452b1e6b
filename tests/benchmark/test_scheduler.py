"""SLURM's answers read (scontrol, sacct, sinfo's GRES) and a job's state reconciled with them,
without a cluster: the real one runs in test_sweep_slurm.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmark.scheduler import SchedulerJob, expand_tasks, parse_gres_gpus, parse_sacct, parse_scontrol
from benchmark.sweep import SweepJob, SweepTarget, read_state, write_state

SCONTROL = """\
JobId=3 ArrayJobId=2 ArrayTaskId=0 ArrayTaskThrottle=1 JobName=s.sh JobState=RUNNING Reason=None Restarts=0 ExitCode=0:0
JobId=2 ArrayJobId=2 ArrayTaskId=1-3%1 JobName=s.sh JobState=PENDING Reason=JobArrayTaskLimit Restarts=0 ExitCode=0:0
JobId=7 JobName=x JobState=PENDING Reason=BeginTime Restarts=1 ExitCode=0:0
JobId=8 JobName=x JobState=TIMEOUT Reason=TimeLimit Restarts=0 ExitCode=0:15
JobId=9 JobName=x JobState=FAILED Reason=NonZeroExitCode Restarts=0 ExitCode=1:0
"""


def test_scontrol_lines_become_one_state_per_array_task():
    jobs = parse_scontrol(SCONTROL)
    assert jobs["2_0"].state == "running"
    assert [jobs[f"2_{t}"].state for t in (1, 2, 3)] == ["queued"] * 3  # a pending range, task by task
    assert jobs["7"].state == "requeued" and jobs["7"].restarts == 1  # pending again after a requeue
    assert jobs["8"].state == "timed out" and jobs["9"].state == "failed" and jobs["9"].exit_code == "1:0"
    assert expand_tasks("1,4-6%2") == [1, 4, 5, 6]


def test_sacct_and_gres():
    jobs = parse_sacct("12_0|CANCELLED by 0|0:0\n12_0.batch|CANCELLED|0:15\n13|COMPLETED|0:0\n")
    assert jobs == {"12_0": SchedulerJob("cancelled", "CANCELLED", None, "0:0"),
                    "13": SchedulerJob("completed", "COMPLETED", None, "0:0")}
    assert parse_gres_gpus("(null)") == 0 and parse_gres_gpus("gpu:a100:4(S:0-1),shard:8") == 4
    assert parse_gres_gpus("gpu:2,gpu:v100:1") == 3


JOB = SweepJob("trase", "hypernerf", None, "main", ("preset=cpu",), 0)


@pytest.mark.parametrize("written, scheduler, expected", [
    ("submitted", SchedulerJob("queued", "PENDING", "Resources"), "queued"),
    ("submitted", SchedulerJob("running", "RUNNING"), "running"),
    ("submitted", SchedulerJob("cancelled", "CANCELLED"), "cancelled"),
    ("submitted", SchedulerJob("unknown", "UNKNOWN"), "lost"),
    ("submitted", SchedulerJob("failed", "FAILED", exit_code="1:0"), "died"),
    ("running", SchedulerJob("queued", "PENDING", "BeginTime"), "requeued"),
    ("running", SchedulerJob("unknown", "UNKNOWN"), "lost"),
    ("running", SchedulerJob("requeued", "PENDING", "JobHeldUser", restarts=1), "requeued"),
    ("running", SchedulerJob("timed out", "TIMEOUT"), "timed out"),
    ("running", SchedulerJob("preempted", "PREEMPTED"), "cancelled"),
    ("done", SchedulerJob("completed", "COMPLETED"), "done"),
    ("failed", SchedulerJob("failed", "FAILED"), "failed"),
])
def test_a_jobs_state_is_reconciled_with_the_schedulers(tmp_path: Path, written, scheduler, expected):
    target = SweepTarget("s", tmp_path)
    results = tmp_path / "results.json"
    results.write_text("{}")
    # a worker on another host (its pid cannot be checked here): the scheduler's word decides
    write_state(target, JOB, state=written, executor="slurm", scheduler_id="5_0", host="elsewhere", pid=1,
                results=[str(results)])
    st = read_state(target, JOB, {"5_0": scheduler})
    assert st["state"] == expected
    if expected == "lost":
        assert "no longer holds" in st["error"]
    elif expected not in ("done", "failed"):
        assert st["scheduler"].startswith(f"SLURM: {scheduler.raw}")


def test_ids_come_from_content_and_survive_the_trip_through_a_state_file(tmp_path):
    other = SweepJob("trase", "hypernerf", None, "main", ("preset=cpu", "seed=1"), 0)
    assert JOB.id != other.id and JOB.id == SweepJob.from_dict(JOB.to_dict()).id
    assert JOB.id.startswith("trase-hypernerf-synthetic-main-s0-")
    target = SweepTarget.from_dict(SweepTarget("s", tmp_path, None, tmp_path / "c").to_dict())
    assert target.cache_root == tmp_path / "c" and target.state_dir == tmp_path / ".sweep" / "s"


def test_status_without_slurm_says_so_and_submission_refuses(tmp_path, monkeypatch, capsys):
    from benchmark.cli import main
    from benchmark.sweep import load_spec

    spec_path = tmp_path / "s.toml"
    spec_path.write_text('methods = ["trase"]\ndatasets = ["hypernerf"]\n[sequences]\nhypernerf = ["synthetic-tiny"]\n'
                         '[executor]\nkind = "slurm"\n')
    spec = load_spec(spec_path)
    (job,) = spec.jobs()
    write_state(spec, job, state="submitted", executor="slurm", scheduler_id="12_0")
    monkeypatch.setenv("PATH", str(tmp_path / "nothing-here"))  # no scontrol, no sbatch
    assert main(["sweep-status", str(spec_path)]) == 0
    out = capsys.readouterr().out
    assert " queued " in out and "note: SLURM not asked: scontrol not found" in out
    assert main(["sweep", str(spec_path), "--no-wait"]) == 1
    assert "scontrol not found" in capsys.readouterr().err
