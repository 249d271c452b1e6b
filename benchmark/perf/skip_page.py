"""The skip page's current figures, rendered from a ``trase-bench perf skip --json`` file
(docs/skip-runs/current.json): each variant's stage seconds, PSNR, ceiling and mIoU beside the
full schedule's, with the machine that measured them."""

from __future__ import annotations

from benchmark.errors import UserError

SKIP_BEGIN = ("<!-- SKIP:BEGIN (trase-bench perf skip --json docs/skip-runs/current.json --from-json "
              "--write-page docs/skip.md; do not edit by hand) -->")
SKIP_END = "<!-- SKIP:END -->"


def _markdown(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(r) + " |" for r in rows)]


def render_skip_block(data: dict) -> str:
    """The figures of a perf JSON file holding the skip suite: a machine line, how the runs were
    made, and the suite's tables (benchmark.perf.skip.table_rows)."""
    from benchmark.perf.skip import table_rows
    from benchmark.results.perf_page import machine_line

    suite = (data.get("suites") or {}).get("skip")
    if not isinstance(suite, dict) or "runs" not in suite:
        raise UserError("the perf file holds no skip suite: run trase-bench perf skip --json FILE")
    settings = suite.get("settings") or {}
    extra = f", settings {' '.join(settings['overrides'])}" if settings.get("overrides") else ""
    how = (f"One run per variant, one after the other; built-in scene `{settings.get('sequence', '?')}`{extra}. "
           "The last two columns are each variant's seconds over the full schedule's.")
    lines = [f"Machine: {machine_line(data)}.", "", how]
    for header, rows in table_rows(suite["runs"]):
        lines += ["", *_markdown(header, rows)]
    return "\n".join(lines) + "\n"


__all__ = ["SKIP_BEGIN", "SKIP_END", "render_skip_block"]
