"""Tracked ids from a synthetic scene's instance maps, written beside the masks stage's output,
for the tests until trase-bench's masks stage writes tracked masks itself (masks.tracking)."""

from __future__ import annotations

import json


def with_truth_tracks(stages: tuple) -> tuple:
    """``stages`` (benchmark.runner.STAGES) with the masks stage followed by writing each
    training view's instance map as its track ids (0: background; ground truth, so a protocol
    of its own)."""
    from trase_bench_grouping.tracks import ids_path, write_ids

    from benchmark.pipeline.context import synthetic_truth
    from masks.generate import read_instance_map

    masks_run = stages[0]

    def masks_and_tracks(ctx):
        records = masks_run(ctx)
        truth = synthetic_truth(ctx.scene)
        d = records[-1].path
        for v in ctx.scene.train:
            if not ids_path(d, v.name).is_file():
                write_ids(d, v.name, read_instance_map(truth.instance_maps[v.name]))
        (d / "tracks.json").write_text(json.dumps({"source": "synthetic", "n_tracks": truth.n_ids - 1}) + "\n")
        return records

    return (masks_and_tracks, *stages[1:])
