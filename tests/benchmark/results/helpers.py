"""Results records of the current schema for table and report tests (no pipeline run)."""

from __future__ import annotations

from benchmark.cache import config_hash
from benchmark.results import write_results
from benchmark.results.runs import run_dir, run_info, run_name


def config(preset="cpu", **method):
    return {"geometry": {"source": "reconstruct", "preset": preset},
            "masks": {"generator": "synthetic"}, "prompts": {"rule": "gt-first-appearance"},
            "method": {"preset": preset, "render_rule": "alone", "prompts": {"click_rule": "weight"}, **method}}


def record(method, dataset, sequence, miou, macc, variant="synthetic", seconds=10.0, overrides=(),
           study=None, cfg=None, v1=None, name=None, seed=0):
    """A results record; ``miou``/``macc`` are the official metric, ``v1`` (miou, macc) the
    project's (default: the same); ``seed``: the run seed (the group hash is the config's)."""
    cfg = cfg or config()
    group = config_hash(cfg)
    h = config_hash(cfg | {"seed": seed})
    v1 = v1 or (miou, macc)
    return {
        "method": method, "dataset": dataset, "sequence": sequence, "variant": variant,
        "run": run_info(name or run_name(group, seed=seed), list(overrides), not overrides, study,
                        "v" if study else None, seed=seed, group=group),
        "metrics": {"miou": v1[0], "macc": v1[1], "pooled_iou": miou, "metric_version": "v1/bin1", "n_frames": 3,
                    "official": {"miou": miou, "macc": macc, "pooled_iou": miou, "metric_version": "official/bin1"}},
        "stages": {"features": {"seconds": seconds}},
        "config": cfg, "config_hash": h,
    }


def write(root, rec, under=""):
    """Write ``rec`` where the runner would (``under``: e.g. ablations/<study>)."""
    d = run_dir(root / under if under else root, rec["method"], rec["dataset"], rec["sequence"], rec["run"]["name"])
    write_results(d / "results.json", rec)
    return d
