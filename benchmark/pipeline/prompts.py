"""Stage ``prompts``: the automatic clicks on the objects of interest, from the ground truth."""

from __future__ import annotations

from pathlib import Path

from benchmark.cache import StageRecord
from benchmark.config import ConfigError
from benchmark.pipeline.context import SequenceRun
from benchmark.scoring import read_mask

PROMPTS_FILE = "prompts.json"


def run(ctx: SequenceRun) -> list[StageRecord]:
    from benchmark.protocol.prompts import BENCHMARK_RULES, load_or_make_prompts

    protocol, scene = ctx.settings.prompts, ctx.scene
    if protocol.rule not in BENCHMARK_RULES:
        raise ConfigError(f"--set prompts.rule={protocol.rule}: choose {' or '.join(BENCHMARK_RULES)}")
    n_sets = protocol.click_sets
    if n_sets < 1:
        raise ConfigError(f"--set prompts.click_sets={n_sets!r}: a whole number >= 1 (1: the run's own clicks only)")
    # the first clicks and click sets; the corrections are the evaluate stage's (they read the method)
    pcfg = {"rule": protocol.rule, "click_sets": n_sets}
    key = ctx.cache.key("prompts", pcfg, {"gt": ctx.gt_key})

    def work(d: Path) -> dict:
        bp = load_or_make_prompts(d / PROMPTS_FILE, scene.test, lambda i: read_mask(scene.gt_masks[i]),
                                  rule=protocol.rule, click_sets=n_sets)
        return {"view": bp.view, "n_clicks": len(bp.clicks), "frames": bp.frames(),
                "click_sets": 1 + len(bp.alternatives)}

    return [ctx.cache.run("prompts", key, work, pcfg)]


def load_prompts(rec: StageRecord) -> tuple:
    """(BenchmarkPrompts, the prompts file as a dict) of a prompts stage."""
    from benchmark.io import read_json
    from benchmark.protocol.prompts import BenchmarkPrompts

    path = rec.path / PROMPTS_FILE
    as_dict = read_json(path, "prompts file")
    return BenchmarkPrompts.from_dict(as_dict, str(path)), as_dict
