"""What each top-level field of ``results.json`` holds: the reference page's table
(docs/reference/results-file.md) is rendered from FIELDS, and a test holds FIELDS to the
writers (benchmark.results.record.RunRecord, write_results, external predictions)."""

from __future__ import annotations

from pathlib import Path

from benchmark.results.record import SCHEMA

FIELDS_BEGIN = ("<!-- FIELDS:BEGIN (python -m benchmark.results.fields docs/reference/results-file.md; "
                "do not edit by hand) -->")
FIELDS_END = "<!-- FIELDS:END -->"

# field -> (in which runs, what it holds)
FIELDS: dict[str, tuple[str, str]] = {
    "schema": ("every run", f"the file's schema, `{SCHEMA}`; older schemas are refused by tables"),
    "created": ("every run", "when the file was written (UTC, ISO 8601)"),
    "run": ("every run", ("`name` (the run's folder), `kind` (main, run, ablation, external), `overrides` "
            "(the `--set` values), `study` (an ablation's), `seed`, `group` (the config hash without the seed, "
            "shared by the seeds of one config)")),
    "method": ("every run", "the method's registered name, or an external run's `--name`"),
    "dataset": ("every run", "the benchmark: nerfds, hypernerf, neu3d, immersive or technicolor"),
    "sequence": ("every run", "the sequence's name (`synthetic`, `synthetic-tiny`, ... on built-in scenes)"),
    "variant": ("every run", "`real` or `synthetic`: the two never share a table"),
    "synthetic_scene": ("every run", ("the built-in scene's generator version, seed, size and motion; null on "
                        "real data")),
    "metrics": ("every run", ("the `v1` metric's mIoU, mAcc, pooled IoU, frame counts and label, and under "
                "`official` the public script's (the one tables show)")),
    "per_frame": ("every run", "the `v1` metric's IoU and accuracy per test frame"),
    "per_frame_official": ("external", "the official metric's IoU and accuracy per scored frame"),
    "oracle": ("benchmark runs", ("the method's clusters chosen with the ground truth: mIoU, mAcc, clusters; "
               "never the method's score")),
    "ceiling": ("synthetic scenes", ("the geometry's ceiling: every gaussian labelled by the object it shows "
                "most, rendered by the method's rule; per object and per mover (`objects`, `movers`, "
                "`mover_frames`, `object_alpha`)")),
    "stages": ("every run", ("per stage: seconds, peak memory, cache key, whether it was taken from the cache, "
               "and the stage's own facts under `info`")),
    "n_gaussians": ("benchmark runs", "gaussians in the geometry"),
    "n_clusters": ("benchmark runs", "clusters (or classes) of the method"),
    "selected_clusters": ("benchmark runs", "the clusters the prompts selected"),
    "click_clusters": ("benchmark runs", "the cluster each first click chose, in order"),
    "click_sets": ("benchmark runs", ("the other automatic click sets: each set's mIoU and clusters, their "
                   "median, worst and best")),
    "feature_space": ("benchmark runs", "how far apart the clusters lie in feature space (intra, inter)"),
    "geometry_checksum": ("benchmark runs", "a digest of the geometry the method segmented"),
    "storage": ("benchmark runs", "the model's size in bytes: gaussians, features, deformation network"),
    "config": ("every run", "every resolved setting (an external run: the digests of its files)"),
    "config_hash": ("every run", "the hash of `config`; the run's name derives from it"),
    "seeds": ("benchmark runs", "the run seed and the seeds of the masks, geometry, features and clustering"),
    "checksums": ("every run", "digests of the ground truth (`gt`) and the predicted masks (`pred`)"),
    "prompts": ("benchmark runs", ("the first clicks (view, time, pixel) and the other click sets' (`alternatives`); "
                "null for external runs")),
    "corrective": ("corrective protocol", ("the robot user's clicks and undone clicks, mIoU and mAcc after each "
                   "click (`curve`), NoC@85 and NoC@90; null with the first clicks alone")),
    "text": ("text protocol", ("each phrase's view, box, score, mask size and clusters, the models and the rule; "
             "null with clicks")),
    "external": ("external", ("where the predictions came from, their layout and files' digests, the frames "
                 "without a prediction and the files ignored")),
    "scene_dir": ("every run", "the scene's folder"),
    "frames": ("every run", "per test frame: its view, image, ground-truth mask and predicted mask"),
    "versions": ("every run", "Python, the code's commit and the packages that computed the numbers"),
    "machine": ("every run", "the platform, core count, numeric mode and the instruction sets the kernels used"),
}
ADDED_ON_WRITING = ("schema", "created", "versions", "machine")  # record.write_results
EXTERNAL_ONLY = ("per_frame_official", "external")  # benchmark.external.evaluate


def render_fields_block() -> str:
    lines = ["| field | in | what it holds |", "|---|---|---|"]
    lines += [f"| `{name}` | {where} | {what} |" for name, (where, what) in FIELDS.items()]
    return "\n".join(lines) + "\n"


def write_fields_page(page: Path) -> None:
    """Put the table between the page's FIELDS markers."""
    from benchmark.results.figures import write_blocks

    write_blocks(Path(page), [((FIELDS_BEGIN, FIELDS_END), render_fields_block())])


if __name__ == "__main__":  # python -m benchmark.results.fields docs/reference/results-file.md
    import sys

    if len(sys.argv) != 2:
        sys.exit("usage: python -m benchmark.results.fields PAGE (a page with the FIELDS markers)")
    write_fields_page(Path(sys.argv[1]))
    print(f"wrote the results-file fields into {sys.argv[1]}")
