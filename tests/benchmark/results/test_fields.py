"""The results file's reference (docs/reference/results-file.md) lists every field the writers
write, and nothing else."""

import dataclasses

from benchmark.results.fields import ADDED_ON_WRITING, EXTERNAL_ONLY, FIELDS, render_fields_block
from benchmark.results.record import RunRecord


def test_the_fields_are_the_records_and_what_writing_and_external_runs_add():
    written = {f.name for f in dataclasses.fields(RunRecord)} | set(ADDED_ON_WRITING) | set(EXTERNAL_ONLY)
    assert set(FIELDS) == written


def test_a_benchmark_runs_file_holds_documented_fields_only(tiny_run):
    import json

    rec = json.loads((tiny_run / "results.json").read_text())
    assert set(rec) <= set(FIELDS)
    assert set(ADDED_ON_WRITING) <= set(rec)


def test_the_table_has_a_row_per_field():
    rows = render_fields_block().splitlines()[2:]
    assert [r.split(" | ")[0].strip("| `") for r in rows] == list(FIELDS)
