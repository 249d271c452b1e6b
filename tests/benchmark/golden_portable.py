"""The machine-independent golden record of the run settings, recorded before the settings'
redesign so every behaviour-preserving commit is checked on any machine:

- ``configs``: the hash and protocol label of every resolved run config (each method x dataset x
  preset x scene variant x image size, and captures of each rig);
- ``stage_keys``: the cache keys of the golden pipeline cases' stages, with fixed input
  fingerprints (keys hash resolved values, not the preset's name).

The pipeline's results are golden_pipeline.py's; in native numerics its ground-truth-geometry
cases are compared within GT_TOLERANCE (CEILING_TOLERANCE for the geometry's ceiling): features
differ in their last bits between instruction sets, and 40 feature steps leave clusters a click
can tip.

    python -m tests.benchmark.golden_portable --write   # re-record (only for an intended change)
"""

from __future__ import annotations

import argparse
import json
import types
from pathlib import Path

GOLDEN = Path(__file__).with_name("golden") / "portable.json"
METHODS = ("cgc", "opengaussian", "trase", "trase-all", "trase-hard")
DATASETS = ("nerfds", "hypernerf", "neu3d", "immersive", "technicolor")
PRESETS = ("paper", "cpu", "cpu-v4", "cpu-v3", "cpu-v2", "cpu-v1")
SIZES = ((160, 120), (1352, 1014), None)
# instruction sets moved the scores by <= 0.0016 and the ceiling not at all (znver3/AVX2 against
# znver5/AVX-512); a broken stage moves them by tenths
GT_TOLERANCE = 0.05
CEILING_TOLERANCE = 0.01
GT_FIELDS = ("miou", "official_miou", "oracle_miou", "ceiling_miou", "n_gaussians")
# devices pinned: "auto" resolves to the machine's (a GPU's configs hash otherwise)
ON_CPU = {"geometry": {"train": {"device": "cpu"}}, "method": {"features": {"device": "cpu"}}}


def config_cases():
    """(case name, method, dataset or None, overrides, variant or rig, image size) of every config."""
    for m in METHODS:
        for d in DATASETS:
            for p in PRESETS:
                for variant in ("synthetic", "real"):
                    for size in SIZES:
                        yield f"{m}|{d}|{p}|{variant}|{size}", m, d, {"preset": p, **ON_CPU}, variant, size
        for p in PRESETS:
            for mono in (True, False):
                yield f"{m}|capture|{p}|{mono}", m, None, {"preset": p, **ON_CPU}, mono, (800, 800)
    yield "seed3", "trase", "hypernerf", {"seed": 3, "preset": "cpu", **ON_CPU}, "synthetic", (160, 120)


def resolved_configs() -> dict:
    """{case: {"config": hash, "protocol": label}} under the current code."""
    from benchmark.cache import config_hash
    from benchmark.datasets import get_dataset
    from benchmark.methods import get_method
    from benchmark.pipeline.settings import capture_settings, run_settings
    from benchmark.results.runs import protocol, protocol_label

    out = {}
    for case, m, d, ov, variant, size in config_cases():
        method = get_method(m)
        if d is None:
            cfg = capture_settings(method, variant, {"holdout": "none"}, ov, size).to_dict()
        else:
            cfg = run_settings(method, get_dataset(d), variant, ov, size).to_dict()
        out[case] = {"config": config_hash(cfg), "protocol": protocol_label(protocol({"config": cfg}))}
    return out


def stage_keys() -> dict:
    """{golden case: {stage: key}}: the keys a run of each golden pipeline case would use, with
    the scene's and the ground truth's fingerprints fixed (they hash files)."""
    from benchmark.cache import PlanCache
    from benchmark.config import parse_overrides
    from benchmark.datasets import get_dataset
    from benchmark.methods import get_method
    from benchmark.pipeline.context import SequenceRun
    from benchmark.pipeline.settings import run_settings
    from benchmark.runner import STAGES
    from tests.benchmark.golden_pipeline import CASES

    out = {}
    for case, (m, d, sets) in CASES.items():
        method = get_method(m)
        overrides = parse_overrides([*sets, "geometry.train.device=cpu", "method.features.device=cpu"])
        settings = run_settings(method, get_dataset(d), "synthetic", overrides, (160, 120))
        scene = types.SimpleNamespace(train=[], test=[], truth=object())
        cache = PlanCache(Path("/nonexistent-trase-bench-cache"), numerics=settings.machine.numerics)
        ctx = SequenceRun(cache, scene, settings, method, False,
                          scene_key="scene", gt_key="gt")
        for stage in STAGES:
            for rec in stage(ctx):
                ctx.records[rec.stage] = rec
        out[case] = {name: rec.key for name, rec in ctx.records.items()}
    return out


def gt_cases(pipeline_cases: dict) -> dict:
    """The fields compared within a tolerance of the ground-truth-geometry cases of a
    golden_pipeline measurement."""
    return {c: {k: r[k] for k in GT_FIELDS} for c, r in pipeline_cases.items() if c.endswith("-gt")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help=f"record into {GOLDEN}")
    args = ap.parse_args(argv)
    record = {"configs": resolved_configs(), "stage_keys": stage_keys()}
    text = json.dumps(record, indent=1, sort_keys=True) + "\n"
    if args.write:
        GOLDEN.write_text(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
