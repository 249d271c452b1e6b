"""``results.json``: one file per run (``benchmark.results.runs``), the only input of tables.

Everything a reader needs to trust or reproduce a number travels with it: both metric
versions, per-frame raw values, stage timings and memory, the full config and its hash,
package versions, checksums of ground truth and predictions, prompts, seeds, and whether the
data were real or synthetic (the two never share a table).
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import os
import platform
from importlib import metadata
from pathlib import Path

from benchmark.errors import UserError
from benchmark.io import atomic_write_json, read_json

# 2: run identity (``run``, one directory per config); 3: the run seed (``run.seed``, and
# ``run.group``: the config hash without the seed, shared by the seeds of one config)
SCHEMA = "trase-bench/results/3"
LEGACY_SCHEMAS = ("trase-bench/results/1", "trase-bench/results/2")  # readable, never tabulated
REQUIRED = ("schema", "method", "dataset", "sequence", "variant", "metrics", "run", "config", "config_hash")
REQUIRED_METRICS = ("miou", "macc", "pooled_iou", "metric_version", "n_frames", "official")
RUN_KINDS = ("main", "run", "ablation", "external")
VERSIONED_PACKAGES = ("trase-bench", "torch", "numpy", "scipy", "scikit-learn", "numba",
                      "opencv-contrib-python-headless")


class ResultsError(UserError):
    """A results file that cannot be used; the message names the file."""


@functools.lru_cache(maxsize=1)
def code_commit() -> str:
    """The commit of this code (``abc1234``, ``+changes`` when the checkout differs from it;
    "unknown" outside a git checkout): which code computed a result, beside the versions."""
    import subprocess

    root = Path(__file__).resolve().parent.parent.parent
    try:
        out = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, check=True, timeout=10)
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=False).stdout.strip()
        return out.stdout.strip() + ("+changes" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version(), "trase-bench commit": code_commit()}
    for name in VERSIONED_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def machine_info(numeric_mode: str | None = None) -> dict:
    """Where a result was made, including what changes its bits on another machine: the numeric
    mode and what it pins (benchmark.numerics: CPU model, x86-64 levels, the instruction set
    torch's kernels use and the CPU numba compiles for; docs/determinism.md)."""
    from benchmark import numerics

    mode = numeric_mode or os.environ.get(numerics.ENV_MODE) or "native"
    return {
        "platform": platform.platform(),
        "processor": platform.machine(),
        "cpu_count": os.cpu_count(),
        "numerics": numerics.describe(mode),
        **numerics.kernels(),
    }


@dataclasses.dataclass
class RunRecord:
    """What ``trase-bench run`` writes for one sequence (built by benchmark.pipeline.record);
    ``write_results`` adds the schema, time, package versions and machine."""

    run: dict  # benchmark.results.runs.run_info: name, kind, overrides, study, seed, group
    method: str
    dataset: str
    sequence: str
    variant: str  # real | synthetic
    synthetic_scene: dict | None  # benchmark.datasets.truth.SCENE_INFO_KEYS; None on real data
    metrics: dict  # v1 scores (REQUIRED_METRICS) + official
    per_frame: list
    oracle: dict | None  # clusters chosen with the ground truth
    ceiling: dict | None  # truth-labelled gaussians (synthetic scenes)
    stages: dict  # stage -> StageRecord.to_dict()
    n_gaussians: int
    n_clusters: int
    selected_clusters: list
    click_clusters: list | None  # per click of the prompts, in order
    click_sets: dict | None
    feature_space: dict | None
    geometry_checksum: str | None
    storage: dict | None
    config: dict
    config_hash: str
    seeds: dict
    checksums: dict  # gt, pred
    prompts: dict
    scene_dir: str
    frames: list
    # the robot user's clicks, the score after each click, NoC@85 / NoC@90
    # (benchmark.pipeline.corrective); None where the run's prompts were its first clicks alone
    corrective: dict | None = None
    # the text protocol (benchmark.protocol.text): each phrase's view, score, box, mask and
    # clusters, and the models and rule; None where the prompts were clicks
    text: dict | None = None

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def write_results(path: Path, record: RunRecord | dict) -> None:
    """Validate and write atomically; adds schema, time, versions and machine if absent."""
    record = record.to_dict() if isinstance(record, RunRecord) else dict(record)
    record.setdefault("schema", SCHEMA)
    record.setdefault("created", datetime.datetime.now(datetime.timezone.utc).isoformat())
    record.setdefault("versions", package_versions())
    mode = ((record.get("config") or {}).get("machine") or {}).get("numerics", "native")
    record.setdefault("machine", machine_info(mode))
    validate(record, path)
    atomic_write_json(path, record)


def validate(record: dict, path: Path | str = "results") -> dict:
    if not isinstance(record, dict):
        raise ResultsError(f"{path}: results must be a JSON object")
    if "schema" in record and record["schema"] in LEGACY_SCHEMAS:
        raise ResultsError(f"{path}: results written by an older version ({record['schema']}); rerun it")
    missing = [k for k in REQUIRED if k not in record]
    if missing:
        raise ResultsError(f"{path}: results file lacks key {missing[0]!r}")
    if record["schema"] != SCHEMA:
        raise ResultsError(f"{path}: unknown results schema {record['schema']!r} (expected {SCHEMA})")
    run = record["run"]
    if not isinstance(run, dict) or run.get("kind") not in RUN_KINDS or not run.get("name"):
        raise ResultsError(f"{path}: 'run' must name the run and its kind ({', '.join(RUN_KINDS)})")
    seed = run.get("seed")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0 or not isinstance(run.get("group"), str):
        raise ResultsError(f"{path}: 'run' must give its seed (a whole number >= 0) and group (config hash "
                           "without the seed)")
    if record["variant"] not in ("real", "synthetic"):
        raise ResultsError(f"{path}: variant must be 'real' or 'synthetic', got {record['variant']!r}")
    metrics = record["metrics"]
    if not isinstance(metrics, dict):
        raise ResultsError(f"{path}: 'metrics' must be an object")
    missing = [k for k in REQUIRED_METRICS if k not in metrics]
    if missing:
        raise ResultsError(f"{path}: metrics lack key {missing[0]!r}")
    official = metrics["official"]
    if not isinstance(official, dict) or not {"miou", "macc"} <= set(official):
        raise ResultsError(f"{path}: metrics.official must be an object with miou and macc")
    scores = [(f"metrics.{k}", metrics[k]) for k in ("miou", "macc", "pooled_iou")] + \
        [(f"metrics.official.{k}", official[k]) for k in ("miou", "macc")]
    for where, v in scores:
        if v is not None and not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
            raise ResultsError(f"{path}: {where} must be a number in [0, 1] or null, got {v!r}")
    return record


def load_results(path: Path) -> dict:
    return validate(read_json(path, "results file"), path)


def read_any_results(path: Path) -> dict:
    """A results file of this schema (validated) or of a legacy one (returned as read, with
    its ``schema``; only for saying what it is)."""
    rec = read_json(path, "results file")
    if isinstance(rec, dict) and rec.get("schema") in LEGACY_SCHEMAS:
        return rec
    return validate(rec, path)


def total_seconds(record: dict) -> float:
    """Wall time of all stages as computed (reused stages count their original time)."""
    return float(sum(s.get("seconds", 0.0) for s in record.get("stages", {}).values()))
