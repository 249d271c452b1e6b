"""``trase-bench run``: the stages of benchmark.pipeline, per sequence, and the results file.

Every stage goes through the stage cache (benchmark.cache): its key hashes its own config
section and its inputs' keys, so a rerun, or another method on the same scene, reuses the
masks and the reconstruction and says so. Results land in the run's directory,
``<runs>/<method>/<dataset>/<sequence>/<name>/results.json`` (``benchmark.results.runs``: name = --name or
c<config hash>), with predictions beside them.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

from benchmark import numerics
from benchmark.cache import PlanCache, StageCache, StageRecord, config_hash
from benchmark.config import ConfigError, parse_overrides
from benchmark.errors import UserError
from benchmark.io import sha256_files
from benchmark.pipeline import ceiling, command, evaluate, fit, geometry, masks, prompts, tracks
from benchmark.pipeline.context import SequenceRun, render_near, scene_fingerprint
from benchmark.pipeline.record import build_record
from benchmark.pipeline.settings import RunSettings, run_settings
from benchmark.plugins import run_packages
from benchmark.results import package_versions, write_results
from benchmark.results.runs import check_free, run_dir, run_info, run_name

# in order; each adds its stage records to the SequenceRun
STAGES = (masks.run, geometry.run, tracks.run, fit.run, prompts.run, evaluate.run, ceiling.run)


# a method in its own environment (benchmark.methods.command): the benchmark's masks and prompts,
# the method's input folder, the command, the scores (benchmark.pipeline.command)
COMMAND_STAGES = (masks.run, prompts.run, command.inputs, command.run, command.evaluate)
STAGE_PLANS = {"benchmark": STAGES, "command": COMMAND_STAGES}


def stages_of(method) -> tuple:
    """The stages of the method's plan (``Method.stage_plan``; a command method's: "command")."""
    return STAGE_PLANS[getattr(method, "stage_plan", "benchmark")]


@dataclasses.dataclass
class RunOptions:
    method: str
    dataset: str
    sequences: list[str] | None = None  # None: every sequence (synthetic default if no data)
    data_root: Path | None = None
    out_dir: Path = Path("runs")
    cache_dir: Path | None = None  # default <out>/.cache
    overrides: list[str] = dataclasses.field(default_factory=list)  # --set key=value
    jobs: int = 1
    progress: bool = True
    name: str | None = None  # run directory name; None: c<config hash> (benchmark.results.runs)
    study: str | None = None  # set by ablation studies: the run is a variant of this study
    study_variant: str | None = None
    seeds: list[int] | None = None  # run seeds (each its own run, --set seed=S); None: as --set says
    keep_existing: bool = False  # a run whose directory holds results of this config is not redone

    def per_seed(self) -> list[RunOptions]:
        """One options object per run seed (just this one without ``seeds``)."""
        if not self.seeds:
            return [self]
        if any(o.strip().startswith("seed=") for o in self.overrides):
            raise ConfigError("give the run seed either with --seeds or with --set seed=S, not both")
        return [dataclasses.replace(self, seeds=None, overrides=[*self.overrides, f"seed={s}"])
                for s in self.seeds]

    @property
    def cache_root(self) -> Path:
        return Path(self.cache_dir) if self.cache_dir else Path(self.out_dir) / ".cache"


class Reporter:
    """One line per stage on stderr: what ran, what was reused, how long; plus an ETA."""

    def __init__(self, enabled: bool, n_sequences: int):
        self.enabled = enabled
        self.n_sequences = n_sequences
        self.t0 = time.perf_counter()
        self.done_sequences = 0

    def stage(self, seq: str, rec: StageRecord) -> None:
        if not self.enabled:
            return
        what = "reused (cached)" if rec.skipped else f"done in {rec.seconds:.1f}s"
        print(f"  [{seq}] {rec.stage:<9} {what}  peak {rec.peak_rss_mb:.0f} MiB  key {rec.key}",
              file=sys.stderr, flush=True)

    def start(self, seq: str, index: int) -> None:
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.t0
        eta = ""
        if self.done_sequences:
            left = (self.n_sequences - self.done_sequences) * elapsed / self.done_sequences
            eta = f", ETA {left / 60:.1f} min"
        print(f"sequence {index + 1}/{self.n_sequences}: {seq}{eta}", file=sys.stderr, flush=True)

    def finish(self) -> None:
        self.done_sequences += 1


@dataclasses.dataclass
class Prepared:
    """One sequence of a run, resolved: its scene, settings, name and directory."""

    spec: object
    scene: object
    scene_dir: Path
    variant: str
    method: object
    settings: RunSettings
    chash: str
    group: str
    is_default: bool
    name: str
    out_dir: Path

    def context(self, cache: StageCache, progress: bool) -> SequenceRun:
        """What the stages read, on ``cache``."""
        return SequenceRun(cache, self.scene, self.settings, self.method, progress, scene_fingerprint(self.scene),
                           sha256_files(list(self.scene.gt_masks))[:16])


def prepare_sequence(opts: RunOptions, sequence: str | None, create: bool = True) -> Prepared:
    """Find (or generate) the scene and resolve the run's settings (once), name and directory;
    no stage runs."""
    from benchmark.datasets import get_dataset, load_scene
    from benchmark.datasets.synthetic import find_or_generate
    from benchmark.methods import get_method

    spec = get_dataset(opts.dataset)
    scene_dir, variant = find_or_generate(spec.key, sequence, opts.data_root, create=create, precompile=True)
    scene = load_scene(spec.key, scene_dir)
    if not scene.gt_masks:
        raise UserError(f"{scene_dir}: no ground-truth masks for {spec.key}/{scene.sequence}; cannot evaluate "
                        f"(expected gt_masks/ in the scene or {spec.display_name}/{scene.sequence}/gt_masks under the data root; "
                        f"to segment a scene without ground truth: trase-bench fit --scene {scene_dir})")
    method = get_method(opts.method)
    overrides = parse_overrides(opts.overrides)
    views = scene.test or scene.train
    size = (views[0].camera.width, views[0].camera.height) if views else None
    settings = run_settings(method, spec, variant, overrides, size)
    # every stage renders the geometry with the near plane it is trained with (in the scene's key
    # where it is not the default, so stages rendered at another plane are not reused)
    scene = scene.with_near(render_near(settings.geometry.source, settings.geometry.train.near_plane))
    chash = config_hash(settings.to_dict())
    # runs that differ only in their seed share settings.group_hash: one row of a table, over seeds
    group = settings.group_hash
    name = run_name(group, opts.name, with_hash=bool(opts.study), seed=settings.seed)
    out_dir = run_dir(opts.out_dir, method.name, spec.key, scene.sequence, name)
    return Prepared(spec, scene, scene_dir, variant, method, settings, chash, group, settings.is_default, name, out_dir)


def plan_sequence(opts: RunOptions, sequence: str | None) -> list[tuple[str, str, bool]]:
    """(stage, key, finished in the cache) for every stage the run would run, computing none
    and writing nothing (a missing synthetic scene is an error, not generated)."""
    p = prepare_sequence(opts, sequence, create=False)
    check_free(p.out_dir, p.chash)
    ctx = p.context(PlanCache(opts.cache_root, numerics=p.settings.machine.numerics), False)
    plan = []
    for stage in stages_of(p.method):
        for rec in stage(ctx):
            ctx.records[rec.stage] = rec
            plan.append((rec.stage, rec.key, rec.skipped))
    return plan


def run_sequence(opts: RunOptions, sequence: str | None, reporter: Reporter, index: int) -> Path:
    p = prepare_sequence(opts, sequence)
    seq = p.scene.sequence
    reporter.start(seq, index)
    check_free(p.out_dir, p.chash)  # before any work: a run with another config is never overwritten
    path = p.out_dir / "results.json"
    if opts.keep_existing and path.is_file():
        if opts.progress:
            print(f"  [{seq}] kept: {p.out_dir} holds this config's results", file=sys.stderr, flush=True)
        reporter.finish()
        return path

    numerics.check(p.settings.machine.numerics)  # before any stage: the bits its config promises
    ctx = p.context(StageCache(opts.cache_root, numerics=p.settings.machine.numerics), opts.progress)
    for stage in stages_of(p.method):
        for rec in stage(ctx):
            ctx.records[rec.stage] = rec
            reporter.stage(seq, rec)
    p.out_dir.mkdir(parents=True, exist_ok=True)
    evaluate.copy_outputs(ctx.records["evaluate"], p.out_dir)
    _, prompts_dict = prompts.load_prompts(ctx.records["prompts"])
    info = run_info(p.name, opts.overrides, p.is_default, opts.study, opts.study_variant, seed=p.settings.seed,
                    group=p.group)
    record = build_record(ctx, info, p.spec.key, p.variant, p.scene_dir, p.chash, prompts_dict, p.out_dir).to_dict()
    record["versions"] = {**package_versions(), **run_packages(p.method, p.settings)}  # plugins' packages too
    write_results(path, record)
    reporter.finish()
    return path


def run(opts: RunOptions) -> list[Path]:
    """Run one method on the requested sequences (for each run seed); returns the
    results.json paths."""
    from benchmark.datasets import get_dataset

    if opts.seeds:
        return [p for one in opts.per_seed() for p in run(one)]
    spec = get_dataset(opts.dataset)
    sequences = opts.sequences or default_sequences(spec, opts.data_root)
    reporter = Reporter(opts.progress, len(sequences))
    if opts.jobs > 1 and len(sequences) > 1:
        from concurrent.futures import ProcessPoolExecutor

        opts_one = dataclasses.replace(opts, jobs=1)
        with ProcessPoolExecutor(max_workers=opts.jobs) as ex:
            futs = [ex.submit(run_sequence, opts_one, s, Reporter(opts.progress, len(sequences)), i)
                    for i, s in enumerate(sequences)]
            return [f.result() for f in futs]
    return [run_sequence(opts, s, reporter, i) for i, s in enumerate(sequences)]


def default_sequences(spec, data_root: Path | None) -> list[str | None]:
    """The paper's sequences present under the data root; if none, the synthetic default, said
    on stderr where a data root was given (a layout the loader does not know looks empty)."""
    from benchmark.datasets import data_root as real_root
    from benchmark.datasets import find_scene_dir
    from benchmark.datasets.synthetic import sequence_name, synthetic_copy

    root = real_root(data_root)
    found = [s for s in spec.sequences if root and find_scene_dir(spec.key, s, root)]
    if root is not None and not found:
        copy = synthetic_copy(root, spec.key, sequence_name("small"))
        runs = f"running the synthetic scene written there, {copy}" if copy else "running the built-in synthetic scene"
        print(f"note: no {spec.key} sequence under {root} (looked in {root / spec.key}/ and "
              f"{root / spec.display_name}/); {runs}", file=sys.stderr, flush=True)
    return found or [None]
