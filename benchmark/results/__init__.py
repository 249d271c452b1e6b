"""The results side: what a run leaves and everything read from it.

* ``record``: ``results.json``, one file per run (schema, validation, reading and writing);
  its names are re-exported here (``from benchmark.results import load_results``);
* ``runs``: run identity, where a run lives, its protocol, which runs a table may use;
* ``leaderboard``: tables rendered from chosen runs and the paper's published numbers;
* ``report``: one self-contained HTML page per run;
* ``stability``: how much a run's clustering changes with its seed;
* ``figures``: the figures page (docs/figures.md), measured and rendered from its data.

Only ``record`` is imported here, so reading a results file pays for no table library.
"""

from benchmark.results.record import (
    LEGACY_SCHEMAS,
    REQUIRED,
    REQUIRED_METRICS,
    RUN_KINDS,
    SCHEMA,
    VERSIONED_PACKAGES,
    ResultsError,
    RunRecord,
    load_results,
    machine_info,
    package_versions,
    read_any_results,
    total_seconds,
    validate,
    write_results,
)

__all__ = [
    "LEGACY_SCHEMAS",
    "REQUIRED",
    "REQUIRED_METRICS",
    "RUN_KINDS",
    "SCHEMA",
    "VERSIONED_PACKAGES",
    "ResultsError",
    "RunRecord",
    "load_results",
    "machine_info",
    "package_versions",
    "read_any_results",
    "total_seconds",
    "validate",
    "write_results",
]
