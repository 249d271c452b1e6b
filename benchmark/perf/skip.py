"""What skipping work a scene does not need costs and saves, each skip on and off side by side
(``trase-bench perf skip``): seconds per stage, test PSNR, geometry ceiling and mIoU.

Skips measured: ``static`` (static gaussians skip the deformation network,
``geometry.train.static_threshold``) and ``converged`` (the geometry and feature stages stop once
their criterion on held-out training views stops improving, ``geometry.train.stop_*`` and
``method.features.stop_*``; trase.convergence). Each format's built-in scene runs the whole pipeline
(trase, the preset of this machine, reconstructed geometry) once per variant with one stage
cache per scene, so the variants share the masks and nothing else. With ``--scene DIR`` D-NeRF
scenes as published are measured too, each variant a ``trase-bench fit`` as ``perf dnerf`` makes
it (half size, the test split held out, black background): test PSNR / SSIM, validation PSNR and
the foreground IoU of one click on the object against the held-out views' alpha stand where a
synthetic scene has its ceiling and mIoU (real data: a table of their own). One run per variant:
no spread; the ratios are of runs made one after the other on this machine, so its load is in
them. The whole suite takes hours on 2 cores: each finished run prints a line and is appended to
``<out-dir>/skip-runs.jsonl`` (RUNS_FILE), so an interrupted suite keeps what it measured.
"""

from __future__ import annotations

import json
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from benchmark.errors import UserError
from benchmark.perf.common import load_average, table, versions

DATASETS = ["nerfds", "hypernerf", "neu3d", "immersive", "technicolor"]
STATIC_THRESHOLD = 0.01  # chosen on the seed-1 selection scene of the HyperNeRF format (docs/notes/skip.md)
STATIC_TIME_GAP = 5.0  # dB; chosen on the seed-2 and seed-3 selection scenes of that format (docs/notes/skip.md)
STATIC_HOLD_ERROR = 0.2  # above the gap, hold back only what draws pixels off by this; chosen on the same scenes
STOP_INTERVAL = 250  # steps between the stopping checks (the quick suite's tiny schedule: QUICK_STOP_INTERVAL)
RUNS_FILE = "skip-runs.jsonl"  # in the out-dir: a line per finished run or fit, written as each ends


def converged(interval: int) -> list[str]:
    """Both stages stop when converged: a check every ``interval`` steps, two checks without a
    gain (geometry: 0.05 dB of held-out PSNR; features: 1% of the first check's held-out loss,
    the cpu preset's rule), every 10th training view held out (docs/skip.md, "Stages that stop
    when converged")."""
    return [f"geometry.train.stop_interval={interval}", "geometry.train.stop_patience=2",
            "geometry.train.stop_min_delta=0.05", f"method.features.stop_interval={interval}",
            "method.features.stop_patience=2", "method.features.stop_min_delta=0.01"]


STAGES = ("geometry", "features", "fit", "evaluate")
DEFAULT = {"datasets": DATASETS, "sequence": "synthetic", "overrides": []}
QUICK = {"datasets": ["neu3d"], "sequence": "synthetic-tiny",  # 3 frames x 18 cameras: views to hold out
         "overrides": ["geometry.train.iterations=60", "geometry.train.warm_up=10", "geometry.train.static_from=10",
                       "geometry.train.static_interval=20", "method.features.iterations=20",
                       "geometry.train.stop_holdout_every=5", "method.features.stop_holdout_every=5"]}
QUICK_STOP_INTERVAL = 10
HEADER = ["format", "variant", "geometry s", "features s", "test PSNR", "static", "ceiling", "ceiling, training views",
          "ceiling, frames with motion", "ceiling, other frames", "mIoU", "stopped at", "geometry s vs full",
          "features s vs full"]
TRAINING_VIEWS_COLUMN = HEADER.index("ceiling, training views")  # absent from suites run before it existed


SCENE_HEADER = ["scene", "variant", "geometry s", "features s", "test PSNR", "test SSIM", "validation PSNR", "static",
                "foreground IoU, click", "worst view", "foreground IoU, mask prompt", "worst view", "stopped at",
                "geometry s vs full", "features s vs full"]
# D-NeRF scenes with --quick: perf dnerf's short fit, its warm-up and checks early enough to act
QUICK_SCENE = ["geometry.train.warm_up=10", "geometry.train.static_from=10", "geometry.train.static_interval=20",
               "geometry.train.stop_holdout_every=3", "method.features.stop_holdout_every=3"]
FULL = ["method.features.stop_interval=0"]  # the cpu preset stops the feature stage; "full" runs every step


# the reconstruction rendered small first (trase.resolution_schedule), and its gaussians grown with it;
# or the gaussians grown with the spectrum while the views render at full size
RESOLUTION = ["geometry.train.resolution_schedule=frequency"]
PRIMITIVES = [*RESOLUTION, "geometry.train.primitive_schedule=resolution"]
PRIMITIVES_ALONE = ["geometry.train.primitive_schedule=frequency"]


def variants(threshold: float, quick: bool = False, names: list[str] | None = None) -> dict[str, list[str]]:
    """The variants measured: every one, or those ``names`` (in the suite's order)."""
    every = {"full": FULL, "static": [*FULL, f"geometry.train.static_threshold={threshold}",
                                     f"geometry.train.static_time_gap={STATIC_TIME_GAP}",
                                     f"geometry.train.static_hold_error={STATIC_HOLD_ERROR}"],
            "converged": converged(QUICK_STOP_INTERVAL if quick else STOP_INTERVAL),
            "resolution": [*FULL, *RESOLUTION], "resolution+primitives": [*FULL, *PRIMITIVES],
            "primitives": [*FULL, *PRIMITIVES_ALONE]}
    unknown = [n for n in names or [] if n not in every]
    if unknown:
        raise UserError(f"unknown skip variant(s) {', '.join(unknown)} (the suite's: {', '.join(every)})")
    return {k: v for k, v in every.items() if not names or k in names}


def _stage_figures(rec: dict) -> dict:
    """What a run's or a fit's record says of its stages: where each stopped, their seconds, the
    gaussians and how many of them were static."""
    stages = rec["stages"]
    geo = stages["geometry"].get("info") or {}
    stopping = {s: (stages[s].get("info") or {}).get("stopping") for s in ("geometry", "features") if s in stages}
    return {"stopping": {s: {"stopped_at": st["stopped_at"], "cap": st["cap"]} for s, st in stopping.items() if st},
            "seconds": {s: float(stages[s]["seconds"]) for s in STAGES if s in stages},
            "gaussians": int(rec["n_gaussians"]), "static_gaussians": geo.get("static_gaussians", 0)}


def _figures(rec: dict) -> dict:
    geo = rec["stages"]["geometry"].get("info") or {}
    ceiling = rec.get("ceiling") or {}
    movers = ceiling.get("mover_frames") or {}  # the ceiling in the frames where objects move, and the others
    return {**_stage_figures(rec), "test_psnr": geo.get("test_psnr"),
            "ceiling": ceiling.get("miou"), "ceiling_training_views": (ceiling.get("training_views") or {}).get("miou"),
            "ceiling_moving_frames": movers.get("miou"),
            "ceiling_other_frames": movers.get("other_miou"),
            "miou": rec["metrics"]["official"]["miou"], "metric": rec["metrics"]["official"]["metric_version"]}


def for_runs(overrides: list[str]) -> list[str]:
    """The settings a built-in benchmark run reads: all but ``capture.*`` (how a capture of
    one's own is read, which the D-NeRF fits take and a benchmark run refuses)."""
    return [o for o in overrides if not o.strip().startswith("capture.")]


def run(quick: bool = False, echo: Callable[[str], None] = print, dataset: str | None = None,
        overrides: list[str] | None = None, out_dir: Path | None = None, scenes: list | None = None,
        datasets: list[str] | None = None, variant_names: list[str] | None = None) -> dict:
    """``scenes``: D-NeRF scene folders measured after the built-in formats; ``datasets``: the
    formats (default: ``dataset``, else the suite's; ``[]``: none, only the scenes);
    ``variant_names``: only these variants (default all)."""
    from benchmark.perf.pipeline import run_pipeline

    cfg = dict(QUICK if quick else DEFAULT)
    datasets = list(datasets) if datasets is not None else [dataset] if dataset else cfg["datasets"]
    extra = [*cfg["overrides"], *for_runs(overrides or [])]
    vs = variants(STATIC_THRESHOLD, quick, variant_names)
    described = ", ".join(f"{k} [{' '.join(v) or 'as the preset'}]" for k, v in vs.items())
    what = [f"{', '.join(datasets)} ({cfg['sequence']})"] if datasets else []
    if scenes:
        what.append(", ".join(f"dnerf/{Path(d).name}" for d in scenes))
    echo(f"skips on and off, {' and '.join(what)}, trase, settings {' '.join(extra) or '(defaults)'}; "
         f"variants: {described}")
    out_dir = Path(out_dir) if out_dir is not None else Path("perf-out")
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / RUNS_FILE).unlink(missing_ok=True)  # this suite's runs only
    done = _Progress(out_dir / RUNS_FILE, len(datasets) * len(vs) + len(scenes or []) * len(vs), echo)
    runs = []
    with tempfile.TemporaryDirectory(prefix="trase-perf-skip-") as tmp:
        for ds in datasets:
            cache = Path(tmp) / f"cache-{ds}"  # the variants share the scene's masks
            for name, ov in vs.items():
                entry = {"dataset": ds, "variant": name, "overrides": [*extra, *ov]}
                t0 = time.perf_counter()
                try:
                    rec = run_pipeline(ds, cfg["sequence"], entry["overrides"], Path(tmp) / f"out-{ds}-{name}", cache)
                except Exception as exc:  # noqa: BLE001 - reported per run, not hidden
                    entry |= {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc(limit=3)}
                    runs.append(done(entry))
                    continue
                entry |= _figures(rec) | {"wall_seconds": time.perf_counter() - t0}
                runs.append(done(entry))
    if runs:
        echo(tables(runs))
    scene_runs = run_scenes([Path(d) for d in scenes or []], vs, [*(QUICK_SCENE if quick else []), *(overrides or [])],
                            quick, out_dir, echo, done)
    for r in runs + scene_runs:
        if "error" in r:
            echo(f"FAILED {r['dataset']} {r['variant']}: {r['error']}")
    pngs = _plots(runs, out_dir, echo) + _plots(scene_runs, out_dir, echo, score="foreground_iou")
    runs = runs + scene_runs
    return {"pngs": pngs, "description": __doc__.strip().splitlines()[0], "quick": quick,
            "settings": {**cfg, "datasets": datasets, "scenes": [str(d) for d in scenes or []], "overrides": extra,
                         "variants": vs},
            "versions": versions("torch", "numba", "numpy"), "runs": runs,
            "failed": [f"{r['dataset']} {r['variant']}" for r in runs if "error" in r],
            "load_average_end": load_average()}


def run_scenes(scenes: list[Path], vs: dict[str, list[str]], extra: list[str], quick: bool, out_dir: Path,
               echo: Callable[[str], None], done: Callable[[dict], dict] = lambda e: e) -> list[dict]:
    """Each variant a ``trase-bench fit`` of each D-NeRF scene as ``perf dnerf`` makes it, one
    fresh stage cache per scene (its variants share its masks, nothing from earlier runs); the
    table printed. ``extra`` reaches the scenes' fits (the built-in runs get it less ``capture.*``);
    ``done`` is told of each finished fit."""
    from benchmark.captures.fit import FitOptions, fit_capture
    from benchmark.perf.dnerf import QUICK_SET, foreground_iou

    runs = []
    for scene in scenes:
        name = f"dnerf/{scene.name}"
        # a fresh stage cache per scene, shared by its variants only: a stage taken from an
        # earlier run would report that run's seconds as this one's
        with tempfile.TemporaryDirectory(prefix="trase-perf-skip-dnerf-") as cache:
            for variant, ov in vs.items():
                sets = ["capture.image_scale=2", *(QUICK_SET if quick else []), *extra, *ov]
                entry = {"dataset": name, "variant": variant, "overrides": sets}
                t0 = time.perf_counter()
                try:
                    fit_json = fit_capture(FitOptions(scene, out_dir / "skip-dnerf" / scene.name / variant,
                                                      holdout="layout", overrides=sets, cache_dir=Path(cache),
                                                      progress=False))
                    entry |= _fit_figures(json.loads(fit_json.read_text()), foreground_iou(fit_json.parent, echo))
                except Exception as exc:  # noqa: BLE001 - reported per run, not hidden
                    entry |= {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc(limit=3)}
                    runs.append(done(entry))
                    continue
                entry["wall_seconds"] = time.perf_counter() - t0
                runs.append(done(entry))
    if runs:
        echo(tables(runs))
    return runs


def _num(x, places: int) -> str:
    return "-" if x is None else f"{x:.{places}f}"


def _format_row(e: dict, runs: list[dict]) -> list[str]:
    """A built-in format's run as a row of HEADER."""
    ds, name, s = e["dataset"], e["variant"], e["seconds"]
    return [ds, name, f"{s.get('geometry', 0):.0f}", f"{s.get('features', 0):.0f}", _num(e["test_psnr"], 2),
            f"{e['static_gaussians'] / max(e['gaussians'], 1):.0%}", _num(e["ceiling"], 4),
            _num(e.get("ceiling_training_views"), 4), _num(e["ceiling_moving_frames"], 4),
            _num(e["ceiling_other_frames"], 4), f"{e['miou']:.4f}", _stopped(e),
            _ratio(runs, ds, name, "geometry"), _ratio(runs, ds, name, "features")]


def _scene_row(e: dict, runs: list[dict]) -> list[str]:
    """A D-NeRF scene's fit as a row of SCENE_HEADER."""
    name, variant, s, m = e["dataset"], e["variant"], e["seconds"], e["measures"]
    return [name, variant, f"{s.get('geometry', 0):.0f}", f"{s.get('features', 0):.0f}", _num(m.get("test_psnr"), 2),
            _num(m.get("test_ssim"), 4), _num(m.get("validation_psnr"), 2),
            f"{e['static_gaussians'] / max(e['gaussians'], 1):.0%}", _num(e["foreground_iou"], 4),
            _num(e["foreground_worst"], 4), _num(e["foreground_mask_iou"], 4), _num(e["foreground_mask_worst"], 4),
            _stopped(e), _ratio(runs, name, variant, "geometry"), _ratio(runs, name, variant, "features")]


def table_rows(runs: list[dict]) -> list[tuple[list[str], list[list[str]]]]:
    """(header, rows) of the built-in formats' table and of the D-NeRF scenes' (each where it has
    runs), from the suite's entries (its JSON's ``runs``, or the lines of RUNS_FILE)."""
    out = []
    for header, row, mine in ((HEADER, _format_row, lambda r: not r["dataset"].startswith("dnerf/")),
                              (SCENE_HEADER, _scene_row, lambda r: r["dataset"].startswith("dnerf/"))):
        rows = [[r["dataset"], r["variant"], "FAILED"] + [""] * (len(header) - 3) if "error" in r else row(r, runs)
                for r in runs if mine(r)]
        if header is HEADER and not any(r.get("ceiling_training_views") is not None for r in runs if mine(r)):
            header = [h for i, h in enumerate(header) if i != TRAINING_VIEWS_COLUMN]
            rows = [[c for i, c in enumerate(row) if i != TRAINING_VIEWS_COLUMN] for row in rows]
        if rows:
            out.append((header, rows))
    return out


def tables(runs: list[dict]) -> str:
    """The suite's tables as plain text (table_rows)."""
    return "\n\n".join(table(rows, header) for header, rows in table_rows(runs))


class _Progress:
    """Told of each finished run or fit: a line for the user and a line in the runs file."""

    def __init__(self, path: Path, total: int, echo: Callable[[str], None]) -> None:
        self.path, self.total, self.echo, self.n = path, total, echo, 0

    def __call__(self, entry: dict) -> dict:
        self.n += 1
        with self.path.open("a") as f:
            f.write(json.dumps(entry, default=str) + "\n")
        what = f"{entry['dataset']} {entry['variant']}"
        if "error" in entry:
            self.echo(f"[{self.n}/{self.total}] {what}: FAILED ({entry['error']})")
        else:
            s = entry["seconds"]
            score = (f"mIoU {entry['miou']:.4f}" if "miou" in entry
                     else f"foreground IoU {entry['foreground_iou']:.4f}")
            self.echo(f"[{self.n}/{self.total}] {what}: {entry['wall_seconds']:.0f} s (geometry "
                      f"{s.get('geometry', 0):.0f} s, features {s.get('features', 0):.0f} s), {score}")
        return entry


def _fit_figures(rec: dict, fg: dict) -> dict:
    """A fit's figures (fit.json) beside its foreground IoU (perf dnerf's click and mask prompt)."""
    measures = rec.get("image_measures") or {}
    return {**_stage_figures(rec), "measures": measures, "test_psnr": measures.get("test_psnr"),
            "foreground_iou": fg["mean"], "foreground_worst": fg["worst"],
            "foreground_mask_iou": fg["mask"]["mean"], "foreground_mask_worst": fg["mask"]["worst"]}


def _plots(runs: list[dict], out_dir: Path, echo: Callable[[str], None], score: str = "miou") -> list[str]:
    """Per format or scene, ``score`` (mIoU; a D-NeRF scene's foreground IoU) against the
    geometry + features seconds of each variant, the Pareto front marked
    (``skip-<format>.png``, ``skip-dnerf-<scene>.png``)."""
    from benchmark.perf.pareto import pareto_front, plot

    what = {"miou": "mIoU (official metric)", "foreground_iou": "foreground IoU (one click, held-out views)"}[score]
    pngs = []
    for ds in dict.fromkeys(r["dataset"] for r in runs):
        ok = [{"label": r["variant"], "miou": r[score],
               "seconds": r["seconds"].get("geometry", 0.0) + r["seconds"].get("features", 0.0)}
              for r in runs if r["dataset"] == ds and "error" not in r and r[score] is not None]
        if not ok:
            continue
        front = pareto_front([(r["seconds"], r["miou"]) for r in ok])
        png = out_dir / f"skip-{ds.replace('/', '-')}.png"
        kind = "as published" if ds.startswith("dnerf/") else "synthetic"
        plot(ok, front, png, f"skips on {ds} ({kind}): {what} against geometry + features time",
             xlabel="geometry + features time (s)", ylabel=what)
        echo(f"wrote {png} (Pareto front: {', '.join(ok[i]['label'] for i in front)})")
        pngs.append(str(png))
    return pngs


def _stopped(entry: dict) -> str:
    """``geometry all/4000, features 1500/3000`` (``all``: ran to the cap), or nothing."""
    return ", ".join(f"{s} {st['stopped_at'] or 'all'}/{st['cap']}" for s, st in (entry.get("stopping") or {}).items())


def _ratio(runs: list[dict], ds: str, name: str, stage: str) -> str:
    if name == "full":
        return ""
    by = {r["variant"]: r for r in runs if r["dataset"] == ds and "error" not in r}
    if "full" not in by or name not in by:
        return "-"
    full = by["full"]["seconds"].get(stage, 0.0)
    return f"{by[name]['seconds'].get(stage, 0.0) / full:.2f}" if full > 0 else "-"


def read_runs(path: Path) -> list[dict]:
    """The entries of RUNS_FILE (a JSON line each), or of a ``perf --json`` file's skip suite."""
    text = Path(path).read_text()
    try:
        whole = json.loads(text)
    except json.JSONDecodeError:
        return [json.loads(line) for line in text.splitlines() if line.strip()]
    return whole["suites"]["skip"]["runs"] if isinstance(whole, dict) and "suites" in whole else [whole]


if __name__ == "__main__":  # the tables of an interrupted suite: python -m benchmark.perf.skip perf-out/skip-runs.jsonl
    import sys

    if len(sys.argv) != 2:
        sys.exit("usage: python -m benchmark.perf.skip FILE (a perf skip run's skip-runs.jsonl, or its --json file)")
    path = Path(sys.argv[1])
    try:
        entries = read_runs(path)
    except (OSError, json.JSONDecodeError, KeyError) as exc:
        sys.exit(f"{path}: {exc}")
    try:
        print(tables(entries))
    except (KeyError, TypeError) as exc:
        sys.exit(f"{path}: not the runs of perf skip (an entry without {exc})")
