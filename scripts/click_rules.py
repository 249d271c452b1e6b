"""Which cluster every click of a benchmark run chooses under each click rule
(docs/notes/cpu-constants.md).

A run scores its clicks by one rule (``method.prompts.click_rule``); this resolves every click of
its five click sets by each rule on the run's own features and clusters, without rendering. Where
every rule chooses the same clusters for a set, that set's mIoU is the same under each; where one
differs, a run with that rule (``--set method.prompts.click_rule=RULE``) scores it.

    python scripts/click_rules.py runs/trase/hypernerf/synthetic/<run>
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

# (rule, front_share): the rules compared, the front rule at four shares
RULES = [("feature", None), ("weight", None), ("depth", None),
         ("front", 0.2), ("front", 0.25), ("front", 1 / 3), ("front", 0.4)]


def rule_name(rule: str, share: float | None) -> str:
    return rule if share is None else f"{rule} {share:.2f}"


def resolve(gaussians, deformation, labels: np.ndarray, features: np.ndarray, cameras: list,
            clicks: list[tuple[int, float, float]], rules=RULES) -> dict[str, list[int]]:
    """Each rule's name -> the cluster each click [(view index, u, v)] chooses (-1: none)."""
    from trase.prompts import Click, click_to_cluster

    out = {}
    for rule, share in rules:
        extra = {} if share is None else {"front_share": share}
        out[rule_name(rule, share)] = [
            int(click_to_cluster(gaussians, deformation, cameras[int(vi)], Click(float(u), float(v)), labels, 0.5,
                                 rule, 1, features=features, **extra)) for vi, u, v in clicks]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="benchmark run folders (results.json and the stage cache above)")
    args = ap.parse_args()
    from benchmark.scene.folders import open_scene_folder

    for run in args.runs:
        record = json.loads((run / "results.json").read_text())
        folder = open_scene_folder(run)
        g, d = folder.model.gaussians, folder.model.deformation
        labels = np.asarray(folder.model.labels)
        feats = g.features.detach().cpu().numpy()
        cams = [cam for _, cam in folder.views]
        sets = (record.get("click_sets") or {}).get("sets") or [{"set": 0, "clicks": record["prompts"]["clicks"],
                                                                 "miou": record["metrics"]["official"]["miou"]}]
        print(f"{run}: oracle clusters {record['oracle']['clusters'] if record.get('oracle') else '?'}")
        for s in sets:
            chosen = resolve(g, d, labels, feats, cams, s["clicks"])
            agree = len({tuple(v) for v in chosen.values()}) == 1
            head = f"  set {s['set']}: mIoU {s.get('miou', float('nan')):.4f} by the run's rule;"
            print(head, "every rule chooses the same clusters" if agree else
                  "; ".join(f"{k} {v}" for k, v in chosen.items()))


if __name__ == "__main__":
    main()
