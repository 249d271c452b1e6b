"""A sweep's spec: the TOML read and checked into jobs (method, dataset, sequence, variant,
seed) with the target they run on (executor, SLURM parameters, where runs go)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path

from benchmark.errors import UserError

MAIN = "main"
EXECUTORS = ("local", "slurm")
SLURM_KEYS = {"partition": str, "gpus_per_node": int, "cpus_per_task": int, "mem_gb": int, "timeout_min": int,
              "array_parallelism": int, "account": str, "qos": str, "constraint": str, "additional": dict}


class SweepError(UserError):
    pass


@dataclasses.dataclass(frozen=True)
class SweepJob:
    method: str
    dataset: str
    sequence: str | None  # None: the built-in synthetic scene
    variant: str
    overrides: tuple[str, ...]
    seed: int

    @property
    def id(self) -> str:
        """Readable and from content: the same job keeps its id whatever else the spec holds."""
        seq = self.sequence or "synthetic"
        what = json.dumps([self.method, self.dataset, seq, self.variant, list(self.overrides), self.seed])
        return f"{self.method}-{self.dataset}-{seq}-{self.variant}-s{self.seed}-{hashlib.sha1(what.encode()).hexdigest()[:8]}"

    def label(self) -> str:
        return f"{self.method} {self.dataset}/{self.sequence or 'synthetic'} {self.variant} seed {self.seed}"

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "overrides": list(self.overrides)}

    @classmethod
    def from_dict(cls, d: dict) -> SweepJob:
        return cls(d["method"], d["dataset"], d["sequence"], d["variant"], tuple(d["overrides"]), int(d["seed"]))


@dataclasses.dataclass(frozen=True)
class SweepTarget:
    """Where a sweep's jobs put their runs, cache and states: what a submitted job is frozen with."""

    name: str
    out: Path
    data_root: Path | None = None
    cache: Path | None = None

    @property
    def state_dir(self) -> Path:
        return self.out / ".sweep" / self.name

    @property
    def cache_root(self) -> Path:
        return self.cache or self.out / ".cache"

    def run_options(self, job: SweepJob):
        from benchmark.runner import RunOptions

        return RunOptions(method=job.method, dataset=job.dataset, sequences=[job.sequence] if job.sequence else None,
                          data_root=self.data_root, out_dir=self.out, cache_dir=self.cache,
                          overrides=[*job.overrides, f"seed={job.seed}"], progress=False,
                          name=None if job.variant == MAIN else job.variant, keep_existing=True)

    def to_dict(self) -> dict:
        return {k: None if v is None else str(v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> SweepTarget:
        path = lambda v: None if v is None else Path(v)
        return cls(d["name"], Path(d["out"]), path(d.get("data_root")), path(d.get("cache")))


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    name: str
    out: Path
    methods: tuple[str, ...]
    datasets: tuple[str, ...]
    sequences: dict  # dataset -> [sequence]; missing: what `run` would choose
    variants: dict  # name -> [override]
    seeds: tuple[int, ...]
    data_root: Path | None = None
    cache: Path | None = None
    executor: str = "local"
    workers: int = 1  # local executor: processes in parallel
    slurm: dict = dataclasses.field(default_factory=dict)
    path: Path | None = None

    @property
    def target(self) -> SweepTarget:
        return SweepTarget(self.name, self.out, self.data_root, self.cache)

    @property
    def state_dir(self) -> Path:
        return self.target.state_dir

    @property
    def cache_root(self) -> Path:
        return self.target.cache_root

    def jobs(self) -> list[SweepJob]:
        from benchmark.datasets import get_dataset
        from benchmark.runner import default_sequences

        out = []
        for dataset in self.datasets:
            seqs = self.sequences.get(dataset) or default_sequences(get_dataset(dataset), self.data_root)
            for method in self.methods:
                for seq in seqs:
                    for variant, overrides in self.variants.items():
                        for seed in self.seeds:
                            out.append(SweepJob(method, dataset, seq, variant, tuple(overrides), seed))
        return out

    def run_options(self, job: SweepJob):
        return self.target.run_options(job)


def load_spec(path: Path | str, overrides: dict | None = None) -> SweepSpec:
    """Read and check a sweep spec; ``overrides`` (from the command line) replace its
    executor settings: executor, workers and slurm.* keys."""
    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib

    from benchmark.datasets import DATASETS
    from benchmark.methods import METHODS

    path = Path(path)
    if not path.is_file():
        raise SweepError(f"{path}: sweep spec not found")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SweepError(f"{path}: malformed TOML ({exc})") from None
    where = lambda key: f"{path}: {key}"
    known = {"name", "out", "data_root", "cache", "methods", "datasets", "sequences", "variants", "seeds",
             "executor", "slurm"}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise SweepError(where(f"unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})"))

    def strings(key: str, allowed=None) -> tuple[str, ...]:
        v = doc.get(key)
        if not isinstance(v, list) or not v or not all(isinstance(x, str) for x in v):
            raise SweepError(where(f"{key} must be a non-empty list of names"))
        bad = [x for x in v if allowed is not None and x not in allowed]
        if bad:
            raise SweepError(where(f"{key}: unknown {bad[0]!r} (known: {', '.join(sorted(allowed))})"))
        return tuple(v)

    methods = strings("methods", set(METHODS.names()))
    datasets = strings("datasets", set(DATASETS))
    seeds = doc.get("seeds", [0])
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and s >= 0 for s in seeds):
        raise SweepError(where("seeds must be a non-empty list of whole numbers >= 0"))
    variants = doc.get("variants", {MAIN: []})
    if not isinstance(variants, dict) or not variants or not all(
            isinstance(v, list) and all(isinstance(o, str) and "=" in o for o in v) for v in variants.values()):
        raise SweepError(where("variants must map names to lists of KEY=VALUE overrides"))
    sequences = doc.get("sequences", {})
    if not isinstance(sequences, dict) or not all(isinstance(v, list) for v in sequences.values()):
        raise SweepError(where("sequences must map datasets to lists of sequence names"))
    ex = {**doc.get("executor", {}), **{k: v for k, v in (overrides or {}).items() if k in ("kind", "workers")}}
    kind = ex.get("kind", "local")
    if kind not in EXECUTORS:
        raise SweepError(where(f"executor.kind {kind!r}: choose {' or '.join(EXECUTORS)}"))
    workers = ex.get("workers", 1)
    if not isinstance(workers, int) or workers < 1:
        raise SweepError(where("executor.workers must be a whole number >= 1"))
    slurm = {**doc.get("slurm", {}), **(overrides or {}).get("slurm", {})}
    for k, v in slurm.items():
        if k not in SLURM_KEYS:
            raise SweepError(where(f"slurm.{k}: unknown (known: {', '.join(SLURM_KEYS)})"))
        if not isinstance(v, SLURM_KEYS[k]) or isinstance(v, bool):
            raise SweepError(where(f"slurm.{k} = {v!r}: expected {SLURM_KEYS[k].__name__}"))
    base = path.parent
    rel = lambda v: None if v is None else (Path(v) if Path(v).is_absolute() else base / v)
    name = str(doc.get("name", path.stem))
    data_root = rel(doc.get("data_root")) or (Path(os.environ["TRASE_DATA"]) if os.environ.get("TRASE_DATA") else None)
    return SweepSpec(name=name, out=rel(doc.get("out", f"sweeps/{name}")), methods=methods, datasets=datasets,
                     sequences=sequences, variants={k: list(v) for k, v in variants.items()},
                     seeds=tuple(seeds), data_root=data_root, cache=rel(doc.get("cache")), executor=kind,
                     workers=workers, slurm=slurm, path=path)
