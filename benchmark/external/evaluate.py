"""``trase-bench evaluate``: a method's predicted masks, made anywhere, scored into runs.

For every sequence folder of a predictions folder (``benchmark.external.layout``) the ground
truth is found the way ``trase-bench run`` finds it (real data under ``--data-root`` /
``$TRASE_DATA``; a synthetic name such as ``synthetic`` uses the built-in scene, generated if
absent), the masks are scored with both metrics exactly as ``trase-bench score MASKS GT_DIR``
scores them, and one run of kind ``external`` is written per sequence:

    <runs>/<name>/<dataset>/<sequence>/e<8 hex digits>/results.json, pred/<frame>.png

The run's name hashes the prediction files and the ground truth, so the same masks evaluated
again land in the same run and other masks beside it. Every sequence is read and scored
before any run is written, and the runs are staged and moved into place together: an error
leaves no run behind.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import shutil
from pathlib import Path

from benchmark.cache import config_hash
from benchmark.errors import UserError
from benchmark.external.layout import (
    PredictionsError,
    SequencePredictions,
    read_sequence,
    sequence_folders,
)
from benchmark.io import atomic_directory, sha256_files
from benchmark.results import write_results
from benchmark.results.runs import EXTERNAL_PROTOCOL, NAME_RE, check_free, run_dir
from benchmark.scoring import ScoreResult, metric_version, score_directories

V1_KEYS = ("miou", "macc", "pooled_iou", "metric", "metric_version", "n_frames", "both_empty", "missing")
OFFICIAL_KEYS = ("miou", "macc", "pooled_iou", "metric_version", "n_frames", "pixel_macc", "missing", "extra",
                 "notes")


@dataclasses.dataclass
class EvaluateOptions:
    predictions: Path
    dataset: str
    name: str  # the method's name in runs and tables
    layout: str = "auto"
    runs_dir: Path = Path("runs")
    data_root: Path | None = None  # None: $TRASE_DATA
    sequences: list[str] | None = None  # None: every sequence folder


@dataclasses.dataclass
class Evaluated:
    """One sequence, scored, its run not yet written."""

    predictions: SequencePredictions
    files: list[Path]  # the mask files read (copied into the run's pred/)
    record: dict
    run_dir: Path


@dataclasses.dataclass
class Outcome:
    results: list[Path]  # results.json of every run written, in sequence order
    not_evaluated: list[str]  # benchmark sequences with data under the data root and no predictions


def evaluate_predictions(opts: EvaluateOptions) -> Outcome:
    """Score every sequence folder of ``opts.predictions`` and write its run (see the module doc)."""
    from benchmark.datasets import DatasetError, get_dataset

    check_method_name(opts.name)
    root = Path(opts.predictions)
    try:
        spec = get_dataset(opts.dataset)
    except DatasetError as exc:
        raise PredictionsError(f"{root}: cannot evaluate for --dataset {opts.dataset!r}: {exc}") from None
    chosen = choose_sequences(root, spec, opts.sequences)
    layouts = [(seq, read_sequence(folder, opts.layout)) for seq, folder in chosen]  # every folder before any scene
    evaluated = [evaluate_sequence(opts, spec, root, seq, preds) for seq, preds in layouts]
    for e in evaluated:
        check_free(e.run_dir, e.record["config_hash"])
    with contextlib.ExitStack() as stack:  # staged side by side; moved into place when all are written
        for e in evaluated:
            d = stack.enter_context(atomic_directory(e.run_dir))
            (d / "pred").mkdir()
            for f in e.files:
                shutil.copy2(f, d / "pred" / f.name)
            write_results(d / "results.json", e.record)
    skipped = [] if opts.sequences else _not_evaluated(spec, opts.data_root, [s for s, _ in chosen])
    return Outcome([e.run_dir / "results.json" for e in evaluated], skipped)


def check_method_name(name: str) -> None:
    """The name an external method is shown under: a run name's characters, and not a method of
    this benchmark (its runs would share that method's rows)."""
    from benchmark.methods import METHODS

    if not NAME_RE.match(name) or name == "ablations":
        raise UserError(f"--name {name!r}: use letters, digits and . _ = + - (at most 80, not starting with a "
                        "symbol, not 'ablations')")
    if name in METHODS:
        raise UserError(f"--name {name!r} is a method of this benchmark; name the external method otherwise "
                        f"(e.g. {name}-public)")


def choose_sequences(root: Path, spec, wanted: list[str] | None) -> list[tuple[str, Path]]:
    """(sequence, its folder) for every sequence folder of ``root``, or for the ``wanted``
    sequences; real and synthetic sequences never mix."""
    from benchmark.datasets.synthetic import parse_sequence_name

    by_seq: dict[str, Path] = {}
    for folder in sequence_folders(root):
        seq = _sequence_of(spec, folder)
        if seq in by_seq:
            raise PredictionsError(f"{folder}: a second folder for {spec.key}/{seq} (beside {by_seq[seq].name}); "
                                   "keep one")
        by_seq[seq] = folder
    if wanted:
        picked = []
        for w in wanted:
            seq = w if parse_sequence_name(w) else _resolve(spec, w, root / w)
            if seq not in by_seq:
                raise PredictionsError(f"{root}: no predictions for {spec.key}/{seq} (no folder {root / seq})")
            picked.append(seq)
        by_seq = {s: by_seq[s] for s in dict.fromkeys(picked)}
    synthetic = sorted(s for s in by_seq if parse_sequence_name(s))
    real = sorted(s for s in by_seq if not parse_sequence_name(s))
    if synthetic and real:
        raise PredictionsError(f"{root}: predictions for real ({', '.join(real)}) and synthetic "
                               f"({', '.join(synthetic)}) sequences; synthetic and real results never mix: "
                               "evaluate them separately (--sequence)")
    return sorted(by_seq.items())


def _sequence_of(spec, folder: Path) -> str:
    from benchmark.datasets.synthetic import parse_sequence_name

    return folder.name if parse_sequence_name(folder.name) else _resolve(spec, folder.name, folder)


def _resolve(spec, name: str, folder: Path) -> str:
    from benchmark.datasets import DATASETS, DatasetError
    from benchmark.datasets.synthetic import SEQUENCE_NAMES

    try:
        return spec.resolve_sequence(name)
    except DatasetError:
        pass
    hint = ""
    if name in DATASETS or any(name == d.display_name for d in DATASETS.values()):
        hint = "; it looks like a dataset's folder: give that folder as --predictions"
    raise PredictionsError(f"{folder}: not a sequence of {spec.key} (sequences: {', '.join(spec.sequences)}; "
                           f"synthetic: {', '.join(SEQUENCE_NAMES.values())}, with -hard){hint}")


def evaluate_sequence(opts: EvaluateOptions, spec, root: Path, sequence: str,
                      preds: SequencePredictions) -> Evaluated:
    """Find one sequence's ground truth as ``run`` does, score its predictions with both
    metrics and build its record."""
    from benchmark.datasets import load_scene
    from benchmark.datasets.synthetic import find_or_generate

    folder = preds.folder
    scene_dir, variant = find_or_generate(spec.key, sequence, opts.data_root)
    scene = load_scene(spec.key, scene_dir)
    if not scene.gt_masks:
        raise UserError(f"{scene_dir}: no ground-truth masks for {spec.key}/{scene.sequence}; cannot evaluate "
                        f"{folder} (expected gt_masks/ in the scene or {spec.display_name}/{scene.sequence}/gt_masks "
                        "under the data root)")
    gt_dir = Path(scene.extras["gt_dir"])
    v1 = score_directories(preds.masks_dir, gt_dir, "v1", per_object=False)
    official = score_directories(preds.masks_dir, gt_dir, "official", per_object=False)
    files = preds.mask_files()
    record = build_record(opts.name, spec.key, variant, scene, scene_dir, root, preds, files, v1, official)
    out = run_dir(opts.runs_dir, opts.name, spec.key, scene.sequence, record["run"]["name"])
    return Evaluated(preds, files, record, out)


def build_record(name: str, dataset: str, variant: str, scene, scene_dir: Path, root: Path,
                 preds: SequencePredictions, files: list[Path], v1: ScoreResult, official: ScoreResult) -> dict:
    """The run record of one sequence's external predictions (results.json; ``write_results``
    adds the schema, time, package versions and machine)."""
    digests = {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in files}
    gt_key = sha256_files(list(scene.gt_masks))[:16]  # as a run records it: one scene, one identity
    config = {"external": {"predictions": sha256_files(files), "ground_truth": gt_key}}
    chash = config_hash(config)
    v1d, od = v1.to_dict(), official.to_dict()
    by_stem = {f.stem: f.name for f in files}
    return {
        "run": {"name": f"e{chash[:8]}", "kind": "external", "overrides": [], "study": None, "seed": 0,
                "group": chash},
        "method": name, "dataset": dataset, "sequence": scene.sequence, "variant": variant,
        "synthetic_scene": dict(scene.truth.info) if scene.truth else None,
        "metrics": {**{k: v1d[k] for k in V1_KEYS}, "official": {k: od[k] for k in OFFICIAL_KEYS}},
        "per_frame": v1d["per_frame"], "per_frame_official": od["per_frame"],
        "oracle": None, "ceiling": None, "stages": {}, "prompts": None,
        "config": config, "config_hash": chash,
        "checksums": {"gt": gt_key, "pred": sha256_files(files)[:16]},
        "external": {
            "note": EXTERNAL_PROTOCOL,
            "source": str(root.resolve()), "folder": str(preds.folder.resolve()),
            "masks_dir": str(preds.masks_dir.resolve()), "gt_dir": str(Path(scene.extras["gt_dir"]).resolve()),
            "layout": preds.layout, "iteration_dir": preds.iteration_dir,
            "other_iteration_dirs": list(preds.other_iteration_dirs),
            "metric_versions": {m: metric_version(m) for m in ("v1", "official")},
            "files": digests,
            "missing": v1.missing,  # test frames without a prediction file: v1 scores them empty, official skips them
            "extra": list(official.extra),  # files official ignored (no ground-truth file of that name)
            "ignored": preds.other_entries(),  # entries of the masks folder that are no mask files
        },
        "scene_dir": str(Path(scene_dir).resolve()),
        "frames": [{"frame": f"{i:05d}", "view": v.name, "image": str(v.image_path), "gt": str(gt),
                    "pred": f"pred/{by_stem[f'{i:05d}']}" if f"{i:05d}" in by_stem else None}
                   for i, (v, gt) in enumerate(zip(scene.test, scene.gt_masks))],
    }


def _not_evaluated(spec, data_root: Path | None, evaluated: list[str]) -> list[str]:
    """The benchmark's sequences found under the data root that had no predictions folder."""
    from benchmark.datasets import find_scene_dir
    from benchmark.datasets.synthetic import parse_sequence_name

    if any(parse_sequence_name(s) for s in evaluated):
        return []
    root = data_root or (Path(os.environ["TRASE_DATA"]) if os.environ.get("TRASE_DATA") else None)
    if root is None:
        return []
    return [s for s in spec.sequences if s not in evaluated and find_scene_dir(spec.key, s, root)]
