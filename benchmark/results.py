"""``results.json``: one file per (method, dataset, sequence), the only input of tables.

Everything a reader needs to trust or reproduce a number travels with it: both metric
versions, per-frame raw values, stage timings and memory, the full config and its hash,
package versions, checksums of ground truth and predictions, prompts, seeds, and whether the
data were real or synthetic (the two never share a table).
"""

from __future__ import annotations

import datetime
import os
import platform
from importlib import metadata
from pathlib import Path

from benchmark.errors import UserError
from benchmark.io import atomic_write_json, read_json

SCHEMA = "trase-bench/results/1"
REQUIRED = ("schema", "method", "dataset", "sequence", "variant", "metrics")
REQUIRED_METRICS = ("miou", "macc", "pooled_iou", "metric_version", "n_frames")
VERSIONED_PACKAGES = ("trase-bench", "torch", "numpy", "scipy", "scikit-learn", "numba",
                      "opencv-contrib-python-headless")


class ResultsError(UserError):
    """A results file that cannot be used; the message names the file."""


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in VERSIONED_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def machine_info() -> dict:
    return {
        "platform": platform.platform(),
        "processor": platform.machine(),
        "cpu_count": os.cpu_count(),
    }


def results_path(out_dir: Path, method: str, dataset: str, sequence: str) -> Path:
    return Path(out_dir) / method / dataset / sequence / "results.json"


def write_results(path: Path, record: dict) -> None:
    """Validate and write atomically; adds schema, time, versions and machine if absent."""
    record = dict(record)
    record.setdefault("schema", SCHEMA)
    record.setdefault("created", datetime.datetime.now(datetime.timezone.utc).isoformat())
    record.setdefault("versions", package_versions())
    record.setdefault("machine", machine_info())
    validate(record, path)
    atomic_write_json(path, record)


def validate(record: dict, path: Path | str = "results") -> dict:
    if not isinstance(record, dict):
        raise ResultsError(f"{path}: results must be a JSON object")
    missing = [k for k in REQUIRED if k not in record]
    if missing:
        raise ResultsError(f"{path}: results file lacks key {missing[0]!r}")
    if record["schema"] != SCHEMA:
        raise ResultsError(f"{path}: unknown results schema {record['schema']!r} (expected {SCHEMA})")
    if record["variant"] not in ("real", "synthetic"):
        raise ResultsError(f"{path}: variant must be 'real' or 'synthetic', got {record['variant']!r}")
    metrics = record["metrics"]
    if not isinstance(metrics, dict):
        raise ResultsError(f"{path}: 'metrics' must be an object")
    missing = [k for k in REQUIRED_METRICS if k not in metrics]
    if missing:
        raise ResultsError(f"{path}: metrics lack key {missing[0]!r}")
    for k in ("miou", "macc", "pooled_iou"):
        v = metrics[k]
        if v is not None and not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
            raise ResultsError(f"{path}: metrics.{k} must be a number in [0, 1] or null, got {v!r}")
    return record


def load_results(path: Path) -> dict:
    return validate(read_json(path, "results file"), path)


def find_results(root: Path) -> list[dict]:
    """Every results.json under ``root`` (validated), each with its path under ``_path``."""
    root = Path(root)
    if not root.is_dir():
        raise ResultsError(f"{root}: results directory not found")
    out = []
    for p in sorted(root.rglob("results.json")):
        rec = load_results(p)
        rec["_path"] = str(p)
        out.append(rec)
    return out


def total_seconds(record: dict) -> float:
    """Wall time of all stages as computed (reused stages count their original time)."""
    return float(sum(s.get("seconds", 0.0) for s in record.get("stages", {}).values()))
