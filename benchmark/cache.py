"""The stage cache: each pipeline stage's output lives under a key of its inputs and config.

``<root>/<stage>/<key>/`` holds a finished stage; ``_stage.json`` inside it records how it was
made. Work in progress lives in ``<root>/<stage>/<key>.partial/`` and is renamed into place
only when the stage function returns, so a killed run never leaves a directory that looks
finished. Whoever computes a stage holds ``<root>/<stage>/<key>.lock`` meanwhile, so workers
sharing the cache compute each stage once (``benchmark.stage_lock``: stale locks of dead
workers are broken). A partial directory is kept on failure: stages that checkpoint (reconstruction)
resume from what it holds; others simply overwrite their files.

Keys hash the stage name, the stage's own config, the keys of its inputs, the stage's code
version (``STAGE_VERSIONS``) and the numeric mode it computes in (``benchmark.numerics``), so a
change anywhere upstream gives every downstream stage a new key, and another method run on the
same scene finds the shared upstream stages (masks, reconstruction) already done.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from benchmark import numerics as numeric_modes
from benchmark.io import atomic_write_json, read_json
from benchmark.stage_lock import HEARTBEAT_S, STALE_AFTER_S, StageLock

STAGE_FILE = "_stage.json"

# Keys hash configs, not code. When a stage's code changes what it writes for the same config,
# bump its version here so outputs of the older code are not reused. Version 1 adds nothing
# to the key (caches of never-bumped stages stay valid).
STAGE_VERSIONS: dict[str, int] = {
    "features": 2,  # 2: smoothing with K=0 normalises features (raw features before)
    "ceiling": 7,  # 2: object alpha statistics; votes from at most 600 training views; 3: per object (objects); 4: spill; 5: spill of all objects only; 6: movers and mover_frames; 7: training_views
    "fit": 2,  # 2: records the clustering sample's size (cluster_sample)
    "command-inputs": 2,  # 2: each click of prompts.json says whether it is positive
    "prompts": 2,  # 2: a click per object in its first frame, each naming its frame (prompts file v3)
    # scores, oracle and click sets; bump when scoring or segmentation code changes what it
    # writes for the same inputs
    "evaluate": 2,  # 2: Gaussian Grouping's and SA4D's oracle takes no class 0 ("no track"), as their clicks
}


def config_hash(obj) -> str:
    """Stable short hash of a JSON-able object (sorted keys)."""
    blob = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


@dataclasses.dataclass
class StageRecord:
    stage: str
    key: str
    path: Path
    skipped: bool  # True when a finished output was reused
    seconds: float  # wall time when it was computed (the original time if skipped)
    peak_rss_mb: float  # peak resident memory of the process while it ran
    info: dict  # what the stage function returned (small JSON-able facts)

    def to_dict(self) -> dict:
        return {
            "key": self.key,
            "skipped": self.skipped,
            "seconds": round(self.seconds, 3),
            "peak_rss_mb": round(self.peak_rss_mb, 1),
            **({"info": self.info} if self.info else {}),
        }


class StageCache:
    """Stages by key under ``root``. Many processes (on many machines, on a shared
    filesystem) may use one cache: a stage is computed by whoever takes its lock
    (``benchmark.stage_lock``); the others wait for the finished stage and reuse it. Stages
    computed in another numeric mode have other keys (native keys are those from before the
    modes existed)."""

    def __init__(self, root: str | Path, heartbeat_s: float = HEARTBEAT_S, stale_after_s: float = STALE_AFTER_S,
                 poll_s: float = 1.0, numerics: str = numeric_modes.DEFAULT):
        self.root = Path(root)
        self.heartbeat_s, self.stale_after_s, self.poll_s = heartbeat_s, stale_after_s, poll_s
        self.numerics = numerics

    def key(self, stage: str, config: dict, inputs: dict[str, str] | None = None) -> str:
        payload = {"stage": stage, "config": config, "inputs": inputs or {}}
        if self.numerics != "native":  # portable: its pinning's bits (the first pinning's keys name none)
            pinning = numeric_modes.PINNING
            payload["numerics"] = self.numerics + (f"/{pinning}" if pinning > 1 else "")
        version = STAGE_VERSIONS.get(stage, 1)
        if version != 1:
            payload["code_version"] = version
        return config_hash(payload)

    def path(self, stage: str, key: str) -> Path:
        return self.root / stage / key

    def is_done(self, stage: str, key: str) -> bool:
        return (self.path(stage, key) / STAGE_FILE).is_file()

    def run(
        self,
        stage: str,
        key: str,
        fn: Callable[[Path], dict | None],
        config: dict | None = None,
    ) -> StageRecord:
        """Return the finished stage ``key``, computing it with ``fn(work_dir)`` if needed."""
        final = self.path(stage, key)
        lock = StageLock(final.with_name(key + ".lock"), self.heartbeat_s, self.stale_after_s)
        if self.is_done(stage, key):
            holder = lock.holder()
            if lock.is_stale(holder):  # its holder died after finishing, before unlocking
                lock.break_stale(holder)
            return self._finished(stage, key)
        waited = False
        while not lock.acquire():
            if self.is_done(stage, key):  # another worker finished it while we waited
                return self._finished(stage, key)
            holder = lock.holder()
            if lock.is_stale(holder):
                lock.break_stale(holder)
                continue
            if not waited and holder is not None:
                print(f"  [{stage}] waiting for {holder.get('host')}:{holder.get('pid')} to finish {key}",
                      file=sys.stderr, flush=True)
                waited = True
            time.sleep(self.poll_s)
        try:
            if self.is_done(stage, key):  # finished between our check and our lock
                return self._finished(stage, key)
            return self._compute(stage, key, fn, config, final)
        finally:
            lock.release()

    def _finished(self, stage: str, key: str) -> StageRecord:
        final = self.path(stage, key)
        meta = read_json(final / STAGE_FILE, "stage record")
        return StageRecord(stage, key, final, True, meta.get("seconds", 0.0),
                           meta.get("peak_rss_mb", 0.0), meta.get("info", {}))

    def _compute(self, stage: str, key: str, fn: Callable[[Path], dict | None], config: dict | None,
                 final: Path) -> StageRecord:
        partial = final.with_name(key + ".partial")
        partial.mkdir(parents=True, exist_ok=True)
        with PeakMemory() as mem:
            t0 = time.perf_counter()
            info = fn(partial) or {}
            seconds = time.perf_counter() - t0
        for stray in sorted(partial.rglob(".*.tmp"), reverse=True):  # left by writes cut by a kill
            if stray.is_dir():
                shutil.rmtree(stray, ignore_errors=True)
            else:
                stray.unlink(missing_ok=True)
        meta = {"stage": stage, "key": key, "config": config or {}, "seconds": seconds,
                "peak_rss_mb": mem.peak_mb, "info": info, "finished": time.time()}
        atomic_write_json(partial / STAGE_FILE, meta)
        if final.exists():  # a stale directory without a stage record
            shutil.rmtree(final)
        os.replace(partial, final)
        return StageRecord(stage, key, final, False, seconds, mem.peak_mb, info)


def current_rss_mb() -> float:
    """Resident memory of this process in MiB (Linux /proc; falls back to ru_maxrss)."""
    try:
        with open("/proc/self/statm") as f:
            pages = int(f.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


class PeakMemory:
    """Samples resident memory in a background thread; ``peak_mb`` after the block."""

    def __init__(self, interval: float = 0.05):
        self.interval = interval
        self.peak_mb = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _poll(self) -> None:
        while not self._stop.is_set():
            self.peak_mb = max(self.peak_mb, current_rss_mb())
            self._stop.wait(self.interval)

    def __enter__(self) -> PeakMemory:  # noqa: PYI034 - typing.Self needs Python 3.11
        self.peak_mb = current_rss_mb()
        self._thread = threading.Thread(target=self._poll, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.peak_mb = max(self.peak_mb, current_rss_mb())


class PlanCache(StageCache):
    """Answers what a run would do without doing it: ``run`` returns the finished stage's
    record (skipped) or a record of a stage to compute (not skipped), never calling ``fn``."""

    def run(self, stage: str, key: str, fn, config: dict | None = None) -> StageRecord:
        if self.is_done(stage, key):
            return self._finished(stage, key)
        return StageRecord(stage, key, self.path(stage, key), False, 0.0, 0.0, {})
