"""Run identity: where a run lives, what protocol it followed, which runs a table may use.

A run is one method on one sequence with one resolved config. It lives in

    <runs>/<method>/<dataset>/<sequence>/<name>/results.json

where ``name`` is ``--name`` or ``c`` + the first 8 hex digits of the resolved config's hash:
a rerun with the same config lands in the same directory, a run with another config in
another, and a named run is never overwritten by a run with another config.

Kinds of run (``results["run"]``):

* main: its config is the method's defaults, outside any study; the leaderboard's default
  row of a method;
* run: made with ``--set`` overrides that change the config; shown only when selected;
* ablation: a variant of an ablation study (``trase-bench ablate``), kept under
  ``<runs>/ablations/<study>/``; never in a leaderboard unless selected;
* external: a method's predicted masks made outside the benchmark and scored by
  ``trase-bench evaluate`` (``benchmark.external``); shown beside the main runs, with the
  protocol ``EXTERNAL_PROTOCOL``.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from benchmark.errors import UserError
from benchmark.numerics import BASELINE, PINNING, pinning_name
from benchmark.results.record import (
    LEGACY_SCHEMAS,
    RUN_KINDS,
    ResultsError,
    load_results,
    read_any_results,
)

NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._=+-]{0,79}$")
EXTERNAL_PROTOCOL = "external predictions: prompts and geometry not controlled by the benchmark"
TABLE_KINDS = ("main", "external")  # what a leaderboard shows unless told otherwise
# masks.tracking -> the protocol's "tracks" label (absent where tracking is none): ids from the
# synthetic scene's ground truth are a protocol of their own, never a tracker's
TRACKS_PROTOCOL = {
    "synthetic": "tracked from ground truth (synthetic instance maps)",
    "files": "tracked ids from files (masks.tracks_dir)",
    "classical": "tracked by the classical tracker (mask overlap after warping by the geometry)",
}


class RunError(UserError):
    """A run that cannot be written or chosen; the message names the directory."""


def run_name(config_hash: str, name: str | None = None, with_hash: bool = False, seed: int = 0) -> str:
    """The run's directory name: ``name`` (checked) or ``c<8 hex digits of the config hash>``;
    ``with_hash``: ``<name>-c<hash>`` (a study's variant: its label, and a rerun with other
    --set values lands beside it). ``config_hash`` is the hash without the run seed, and a
    seed other than 0 adds ``-s<seed>``: the seeds of one config sit side by side."""
    tag = f"c{config_hash[:8]}"
    suffix = f"-s{seed}" if seed else ""
    if name is None:
        return tag + suffix
    if not NAME_RE.match(name):
        raise RunError(f"--name {name!r}: use letters, digits and . _ = + - (at most 80, not starting "
                       "with a symbol)")
    return (f"{name}-{tag}" if with_hash else name) + suffix


def run_dir(out_dir: Path, method: str, dataset: str, sequence: str, name: str) -> Path:
    return Path(out_dir) / method / dataset / sequence / name


def run_info(name: str, overrides: list[str], defaults: bool, study: str | None = None,
             variant: str | None = None, seed: int = 0, group: str | None = None) -> dict:
    """The ``run`` block of a results file: its name, kind, overrides, study, run seed and
    group (the config hash without the seed). ``defaults``: whether the resolved config, seed
    aside, equals the method's defaults (a ``--set`` restating a default still makes a main
    run; so does another seed)."""
    kind = "ablation" if study else ("main" if defaults else "run")
    return {"name": name, "kind": kind, "overrides": list(overrides),
            "study": {"name": study, "variant": variant} if study else None,
            "seed": int(seed), "group": group}


def check_free(directory: Path, config_hash: str) -> None:
    """Refuse to overwrite a run made with another config (same config: a rerun, allowed)."""
    path = Path(directory) / "results.json"
    if not path.exists():
        return
    try:
        old = read_any_results(path)
    except UserError:  # unreadable, truncated, not UTF-8, invalid
        raise RunError(f"{directory}: holds an unreadable results.json; remove the directory or choose "
                       "another --name") from None
    if old.get("config_hash") != config_hash:
        raise RunError(f"{directory}: a run with another config exists (config {old.get('config_hash')}, "
                       f"this one {config_hash}); choose another --name or remove that directory")


# -- protocol ---------------------------------------------------------------------------------
def protocol(record: dict) -> dict:
    """What a number was measured under, from the run's config and metric: the labels a table
    prints beside it. An external run's prompts and geometry are its maker's: its protocol says
    so (``EXTERNAL_PROTOCOL``) beside the scene and the metric."""
    cfg = record.get("config") or {}
    geo, mcfg = cfg.get("geometry", {}), cfg.get("method", {})
    src = geo.get("source", "?")
    click_settings = mcfg.get("prompts") or {}
    clicks = click_settings.get("click_rule")
    if clicks == "front":  # the rule is defined by its share
        clicks += f" {click_settings.get('front_share', '?')}"
    prompts = (cfg.get("prompts") or {}).get("rule", "?") + (f", click {clicks}" if clicks else "")
    if "cgc" in mcfg:
        prompts += ", cgc patch query"
    prompts += corrective_protocol(cfg, record.get("corrective"))
    if (cfg.get("prompts") or {}).get("source") == "text":  # benchmark.protocol.text
        prompts = (record.get("text") or {}).get("label") or "text"
    official = (record.get("metrics") or {}).get("official") or {}
    syn = record.get("synthetic_scene")
    scene = {}
    if syn:  # which generated scene: another seed or difficulty is another scene under one name
        scene["scene"] = (f"synthetic v{syn.get('generator_version')} {syn.get('size')} seed {syn.get('seed')} "
                          f"{syn.get('difficulty')}")

    def on(section: dict) -> str:
        """Where it trained, named when not the CPU (gsplat's kernels give other bits than the
        numba ones; records from before the device setting trained on the CPU)."""
        device = section.get("device", "cpu")
        return "" if device == "cpu" else f", on {device}"

    if (record.get("run") or {}).get("kind") == "external":
        return {"external": EXTERNAL_PROTOCOL} | scene | {"metric": official.get("metric_version", "?")}
    out = scene | {
        "geometry": (f"{src} ({geo.get('preset')} preset{on(geo.get('train') or {})})" if src == "reconstruct"
                     else src),
        "features": mcfg.get("preset", "?") + on(mcfg.get("features") or {}),
        "masks": (cfg.get("masks") or {}).get("generator", "?"),
        **tracks_protocol(cfg.get("masks") or {}),
        "prompts": prompts,
        "render": mcfg.get("render_rule", "alone"),
        "numerics": numerics_protocol(cfg, record.get("machine")),
        "metric": official.get("metric_version", "?"),
    }
    if "command" in mcfg:  # a method in its own environment (benchmark.methods.command)
        out |= {"geometry": "the method's own (a command method)",
                "features": f"the method's own (TOML sha256 {str(mcfg.get('toml_sha256', '?'))[:12]})",
                "render": "the method's own"}
    return out


def corrective_protocol(cfg: dict, corrective: dict | None) -> str:
    """The robot user's part of a run's prompts label (benchmark.protocol.corrective): its
    budget per first click and target, and "positive only" where a run's method took no negative
    clicks (known from its record); nothing for the first clicks alone (records from before the
    protocol among them)."""
    prompts = cfg.get("prompts") or {}
    per_object = prompts.get("corrections", 0)
    if not per_object:
        return ""
    if "command" in (cfg.get("method") or {}):  # a command method runs once, on the first clicks
        return ", first clicks only (the method runs once)"
    polarity = ", positive only" if corrective is not None and not corrective.get("negatives") else ""
    checks = prompts.get("correction_check_frames", 0)  # absent: records of protocol 2, click frames alone
    watched = f" watching {checks} check frames" if checks else ""
    radius = prompts.get("correction_undone_radius", 0)  # absent: an undone click's region left alone
    tries = prompts.get("correction_region_tries", 0)  # absent: no limit
    retry = (f" retrying {radius:g} px from undone clicks" + (f", {tries} tries per region" if tries else "")) if radius else ""
    return f", corrective {per_object}/object to IoU {prompts.get('correction_target', '?')}{watched}{retry}{polarity}"


def numerics_protocol(cfg: dict, machine: dict | None = None) -> str:
    """The numeric mode of a run's config (benchmark.numerics): portable bits name their baseline
    and, from the second on, their pinning (``machine``: the record's, whose records without one
    are of the first; None: a record not written yet, of this process's); records from before the
    modes computed natively."""
    mode = (cfg.get("machine") or {}).get("numerics", "native")
    pinning = numerics_pinning(cfg, machine)  # 1 for native runs
    return mode if mode != "portable" else " ".join(filter(None, ("portable", BASELINE, pinning_name(pinning))))


def numerics_pinning(cfg: dict, machine: dict | None) -> int:
    """The pinning of a portable run's bits (benchmark.numerics.PINNING; ``machine`` as in
    ``numerics_protocol``); 1 for native runs, whose bits no pinning names."""
    if (cfg.get("machine") or {}).get("numerics", "native") != "portable":
        return 1
    return PINNING if machine is None else int((machine.get("numerics") or {}).get("pinning", 1))


def tracks_protocol(masks: dict) -> dict:
    """{"tracks": label} of a run's masks section where it tracked ids across views, else {}
    (records from before tracking, and untracked runs, have no tracking field)."""
    tracking = masks.get("tracking", "none")
    if tracking in (None, "none"):
        return {}
    return {"tracks": TRACKS_PROTOCOL.get(tracking, tracking)}


def protocol_label(p: dict) -> str:
    return "; ".join(v if k == "external" else f"{k} {v}" for k, v in p.items())


class ProtocolLegend:
    """Footnote markers [a], [b], ... for protocol labels, in order of first appearance."""

    def __init__(self) -> None:
        self.keys: dict[str, str] = {}  # label -> marker

    def key(self, label: str) -> str:
        if label not in self.keys:
            n = len(self.keys)
            self.keys[label] = chr(ord("a") + n) if n < 26 else str(n)
        return self.keys[label]

    def marks(self, labels) -> str:
        """' [a, c]' for the labels (empty ones ignored), '' for none."""
        keys = sorted(self.key(lab) for lab in labels if lab)
        return f" [{', '.join(keys)}]" if keys else ""

    def notes(self) -> list[str]:
        return [f"[{k}] {lab}" for lab, k in self.keys.items()]


# -- finding and choosing runs ------------------------------------------------------------------
def find_runs(root: Path, warn=None) -> list[dict]:
    """Every run under ``root`` (validated), each with ``_path`` and ``_dir``. Results files of
    older schemas (1: before run identity, 2: before run seeds) are skipped with one line on
    stderr."""
    root = Path(root)
    if not root.is_dir():
        raise ResultsError(f"{root}: results directory not found")
    out, legacy = [], []
    for p in sorted(root.rglob("results.json")):
        if any(part.startswith(".") for part in p.relative_to(root).parts):
            continue  # the stage cache and temporary directories
        rec = read_any_results(p)
        if rec["schema"] in LEGACY_SCHEMAS:
            legacy.append(p)
            continue
        out.append(_tag(rec, p))
    if legacy:
        (warn or _stderr)(f"note: skipped {len(legacy)} results file(s) written by an older version "
                          f"(e.g. {legacy[0]}); rerun them to use them")
    return out


def load_run(path: Path) -> dict:
    """One run from its directory or its results.json."""
    path = Path(path)
    file = path / "results.json" if path.is_dir() else path
    if not file.is_file():
        raise RunError(f"{path}: no results.json (not a run directory)")
    return _tag(load_results(file), file)


def _tag(rec: dict, path: Path) -> dict:
    rec["_path"], rec["_dir"] = str(path), str(Path(path).parent)
    return rec


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr)


def kind(record: dict) -> str:
    return record["run"]["kind"]


def row_key(record: dict) -> tuple[str, str, str]:
    return record["method"], record["dataset"], record["sequence"]


def select_runs(records: list[dict], kinds: tuple[str, ...] = TABLE_KINDS) -> list[dict]:
    """The runs of the given kinds (default: the main runs and external predictions)."""
    bad = set(kinds) - set(RUN_KINDS)
    if bad:
        raise RunError(f"unknown run kind {min(bad)!r}; choose from {', '.join(RUN_KINDS)}")
    return [r for r in records if kind(r) in kinds]


def scene_identity(record: dict) -> str | None:
    """What the run was measured on beyond its sequence name: the ground truth's checksum (a
    synthetic scene of another seed has the same name and other ground truth)."""
    return (record.get("checksums") or {}).get("gt")


def seed(record: dict) -> int:
    return int(record["run"]["seed"])


def group(record: dict) -> str:
    """The run's config without its seed, and the pinning its portable bits came from: runs of one
    config under two pinnings are two configs, never one mean."""
    pinning = numerics_pinning(record.get("config") or {}, record.get("machine"))
    return "/".join(filter(None, (record["run"]["group"], pinning_name(pinning))))


def one_config_per_row(records: list[dict]) -> list[dict]:
    """A table cell is one config, measured over one or more run seeds. Two runs whose configs
    differ beyond the seed, or on different scenes under one name, for the same method,
    dataset and sequence are refused, naming them and how to choose; of runs with the same
    config and seed on the same scene (a named rerun of the defaults, say) the newest is kept.
    Returns one run per (row, seed)."""
    by_row: dict[tuple, list[dict]] = {}
    for r in records:
        by_row.setdefault(row_key(r), []).append(r)
    out = []
    for (method, dataset, sequence), recs in sorted(by_row.items()):
        configs = {group(r) for r in recs}
        scenes = {scene_identity(r) for r in recs}
        if len(configs) > 1 or len(scenes) > 1:
            what = "different configs" if len(configs) > 1 else "different scenes (ground truth)"
            dirs = ", ".join(f"{r['_dir']} ({kind(r)}, made {str(r.get('created', '?'))[:16]})" for r in recs)
            raise RunError(f"{method} on {dataset}/{sequence}: {len(recs)} runs with {what}: {dirs}; "
                           "choose one with --run DIR (or remove the stale one)")
        out += newest_per_seed(recs)
    return out


def newest_per_seed(records: list[dict]) -> list[dict]:
    """Of runs of one config, the newest of each seed (a rerun replaces), in seed order."""
    newest: dict[int, dict] = {}
    for r in sorted(records, key=lambda r: str(r.get("created", ""))):
        newest[seed(r)] = r
    return [newest[s] for s in sorted(newest)]


def seed_siblings(record: dict, candidates: list[dict]) -> list[dict]:
    """The runs among ``candidates`` of ``record``'s config on its scene, one per seed (the
    newest), itself included."""
    key = (row_key(record), group(record), scene_identity(record))
    return newest_per_seed([r for r in candidates if (row_key(r), group(r), scene_identity(r)) == key])
