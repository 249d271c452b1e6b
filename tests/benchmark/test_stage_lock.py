"""Stage locks: one holder, stale rules, and many processes on one cache computing a stage once."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from benchmark.cache import STAGE_FILE, StageCache
from benchmark.stage_lock import StageLock


def test_one_holder_and_release(tmp_path):
    a, b = StageLock(tmp_path / "k.lock"), StageLock(tmp_path / "k.lock")
    assert a.acquire() and not b.acquire()
    h = b.holder()
    assert h["pid"] == os.getpid() and h["heartbeat_age_s"] < 5 and not b.is_stale(h)
    a.release()
    assert b.holder() is None and b.acquire()
    b.release()
    assert not (tmp_path / "k.lock").exists()


def test_stale_when_the_holder_is_dead_or_silent(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True)
    pid = int(dead.stdout)
    lock = StageLock(tmp_path / "k.lock", stale_after_s=60)
    import json
    import socket

    (tmp_path / "k.lock").write_text(json.dumps({"host": socket.gethostname(), "pid": pid, "taken": 0}))
    assert lock.is_stale()  # same host, no such process
    (tmp_path / "k.lock").write_text(json.dumps({"host": "another-node", "pid": pid, "taken": 0}))
    assert not lock.is_stale()  # another machine: judged by its heartbeat only
    old = time.time() - 120
    os.utime(tmp_path / "k.lock", (old, old))
    assert lock.is_stale()
    assert lock.break_stale() and not lock.break_stale()  # one breaker wins
    assert lock.acquire()
    lock.release()


def test_a_slow_breaker_puts_back_the_fresh_lock_it_renamed(tmp_path):
    """Two waiters judge a dead holder's lock stale; the first breaks it and takes a fresh
    lock; the second, breaking late, must not remove the first one's lock."""
    import json
    import socket

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True)
    (tmp_path / "k.lock").write_text(json.dumps({"host": socket.gethostname(), "pid": int(dead.stdout), "taken": 0}))
    first, second = StageLock(tmp_path / "k.lock"), StageLock(tmp_path / "k.lock")
    judged_first, judged_second = first.holder(), second.holder()
    assert first.is_stale(judged_first) and second.is_stale(judged_second)
    assert first.break_stale(judged_first) and first.acquire()
    assert not second.break_stale(judged_second)  # the file it renamed was the fresh lock: put back
    assert second.holder()["pid"] == os.getpid() and not second.acquire()
    assert [p.name for p in tmp_path.iterdir()] == ["k.lock"]  # nothing left aside
    first.release()


def test_heartbeat_keeps_a_long_holder_fresh(tmp_path):
    lock = StageLock(tmp_path / "k.lock", heartbeat_s=0.05, stale_after_s=0.5)
    assert lock.acquire()
    old = time.time() - 100
    os.utime(tmp_path / "k.lock", (old, old))
    time.sleep(0.3)
    assert not lock.is_stale()
    lock.release()


def _worker(root: str, counter: str, start: float) -> bool:
    def work(d: Path) -> dict:
        with open(counter, "a") as f:
            f.write("x")
        time.sleep(0.5)
        (d / "out.txt").write_text("done")
        return {}

    while time.time() < start:
        time.sleep(0.001)
    rec = StageCache(root, poll_s=0.05).run("stage", "k", work)
    return rec.skipped


def test_concurrent_workers_compute_a_stage_once(tmp_path):
    ctx = mp.get_context("spawn")
    start = time.time() + 2.0
    with ctx.Pool(3) as pool:
        skipped = pool.starmap(_worker, [(str(tmp_path / "cache"), str(tmp_path / "count"), start)] * 3)
    assert (tmp_path / "count").read_text() == "x"  # computed once
    assert sorted(skipped) == [False, True, True]
    assert (tmp_path / "cache/stage/k/out.txt").read_text() == "done"
    assert not list((tmp_path / "cache/stage").glob("*.lock*"))


def test_a_worker_killed_mid_stage_leaves_nothing_finished(tmp_path):
    root = tmp_path / "cache"
    code = ("import sys, time; from pathlib import Path; from benchmark.cache import StageCache\n"
            "def work(d):\n    (d / 'half').write_text('x'); time.sleep(60)\n"
            f"StageCache({str(root)!r}).run('stage', 'k', work)\n")
    p = subprocess.Popen([sys.executable, "-c", code], env={**os.environ, "PYTHONPATH": str(Path.cwd())})
    try:
        deadline = time.time() + 60
        while not (root / "stage/k.partial/half").exists():
            assert time.time() < deadline, "the stage never started"
            time.sleep(0.05)
        p.send_signal(signal.SIGKILL)
        p.wait()
    finally:
        if p.poll() is None:
            p.kill()
    assert (root / "stage/k.lock").exists() and not (root / "stage/k" / STAGE_FILE).exists()
    rec = StageCache(root, poll_s=0.05).run("stage", "k", lambda d: (d / "out.txt").write_text("ok") and {})
    assert not rec.skipped and (root / "stage/k/out.txt").read_text() == "ok"
    assert not (root / "stage/k.lock").exists() and not (root / "stage/k.partial").exists()


def test_a_lock_left_beside_a_finished_stage_is_cleared(tmp_path):
    """A worker killed after its stage was renamed into place but before it unlocked."""
    import json
    import socket

    root = tmp_path / "cache"
    StageCache(root).run("stage", "k", lambda d: {})
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True)
    (root / "stage/k.lock").write_text(json.dumps({"host": socket.gethostname(), "pid": int(dead.stdout)}))
    assert StageCache(root).run("stage", "k", lambda d: {}).skipped
    assert not (root / "stage/k.lock").exists()
