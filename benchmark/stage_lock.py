"""One writer per stage key, across processes and machines sharing the cache on a network
filesystem.

A lock is the file ``<stage>/<key>.lock``, created with O_CREAT | O_EXCL (atomic on local
filesystems and on NFS v3 and later), holding who took it (host, pid, time). While the
stage computes, a thread touches the file every ``heartbeat_s`` seconds. A lock is stale
when its holder is known dead (same host, no such process) or its heartbeat is older than
``stale_after_s`` (a killed machine, a lost node); a waiter breaks a stale lock by renaming it
to a unique name first (only one waiter's rename succeeds), then takes a fresh one. A waiter
that was too slow may rename the fresh lock of the one that won: it sees that the file is not
the lock it judged stale and puts it back. Why not
``filelock``: its flock-based lock is unreliable on NFS and its soft lock has no stale rule,
so a worker killed mid-stage would block the sweep forever.
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time
import uuid
from pathlib import Path

HEARTBEAT_S = 10.0
STALE_AFTER_S = 120.0


def known_dead(host, pid) -> bool:
    """True when ``pid`` on ``host`` is this machine's and no such process runs (a process on
    another machine, or of another user, cannot be judged dead from here)."""
    if host != socket.gethostname() or not isinstance(pid, int):
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # another user's process: alive
        return False
    return False


class StageLock:
    def __init__(self, path: Path, heartbeat_s: float = HEARTBEAT_S, stale_after_s: float = STALE_AFTER_S) -> None:
        self.path = Path(path)
        self.heartbeat_s = float(heartbeat_s)
        self.stale_after_s = float(stale_after_s)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def acquire(self) -> bool:
        """Take the lock if nobody holds it (no waiting); True when taken."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            return False
        with os.fdopen(fd, "w") as f:
            json.dump({"host": socket.gethostname(), "pid": os.getpid(), "taken": time.time()}, f)
        self._stop.clear()
        self._thread = threading.Thread(target=self._beat, daemon=True, name=f"heartbeat {self.path.name}")
        self._thread.start()
        return True

    def _beat(self) -> None:
        while not self._stop.wait(self.heartbeat_s):
            try:
                os.utime(self.path)
            except FileNotFoundError:  # renamed aside this instant by a slow waiter, who puts it back
                continue

    def release(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self.path.unlink(missing_ok=True)

    def holder(self) -> dict | None:
        """Who holds it (host, pid, taken, age of the heartbeat in s), None when free."""
        try:
            st = self.path.stat()
        except FileNotFoundError:
            return None
        info = _read_holder(self.path)
        info["heartbeat_age_s"] = max(0.0, time.time() - st.st_mtime)
        return info

    def is_stale(self, holder: dict | None = None) -> bool:
        h = holder if holder is not None else self.holder()
        if h is None:
            return False
        if known_dead(h.get("host"), h.get("pid")):
            return True
        return h["heartbeat_age_s"] > self.stale_after_s

    def break_stale(self, judged: dict | None = None) -> bool:
        """Remove a stale lock; True if this call removed it (a rename only one waiter wins).
        ``judged``: the holder() that was found stale; when the file renamed aside is another
        holder's (a faster waiter broke the stale lock and took a fresh one meanwhile), it is
        put back and nothing is broken."""
        aside = self.path.with_name(f"{self.path.name}.broken-{uuid.uuid4().hex[:8]}")
        try:
            os.rename(self.path, aside)
        except FileNotFoundError:
            return False
        if judged is not None and _identity(_read_holder(aside)) != _identity(judged):
            try:
                os.link(aside, self.path)  # put it back, unless yet another lock was taken meanwhile
            except FileExistsError:
                pass
            aside.unlink(missing_ok=True)
            return False
        aside.unlink(missing_ok=True)
        return True


def _read_holder(path: Path) -> dict:
    """What a lock file says (host, pid, taken); {} while it is being written or unreadable."""
    try:
        info = json.loads(path.read_text() or "{}")
    except (OSError, ValueError):
        return {}
    return info if isinstance(info, dict) else {}


def _identity(holder: dict) -> tuple:
    return holder.get("host"), holder.get("pid"), holder.get("taken")


__all__ = ["HEARTBEAT_S", "STALE_AFTER_S", "StageLock", "known_dead"]
