"""The prompt settings behind each figures row. The robot user's settings change a run's clicks,
and so its mIoU and NoC; a data file merged from re-measurements (``figures --update``) may hold
rows measured under other settings than the rest, so the page marks their cells and says how
they differ (as it marks cells of another instruction set: benchmark.results.figures_format)."""

from __future__ import annotations

import json

from benchmark.results.figures_format import by_share, marks_for

PROMPT_MARKS = ("ᵃ", "ᵇ", "ᶜ", "ᵈ")
UNRECORDED = "unrecorded"  # rows summarised before rows kept their prompt settings


def run_prompt_settings(record: dict) -> dict:
    """A run's prompt settings as its config records them (benchmark.pipeline.settings.recorded_settings:
    a setting at its "as before" value is left out, so a missing setting means the rule before it)."""
    return dict((record.get("config") or {}).get("prompts") or {})


def row_prompts(row: dict) -> str:
    """A row's prompt settings as one comparable string; UNRECORDED for rows without them."""
    return json.dumps(row["prompts"], sort_keys=True) if "prompts" in row else UNRECORDED


def prompt_marks(rows: list[dict]) -> dict[str, str]:
    """A mark per prompt setting other than the main one (the most cells')."""
    return marks_for(by_share(rows, row_prompts)[1:], PROMPT_MARKS)


def _difference(settings: dict, main: dict) -> str:
    """How ``settings`` differ from ``main``: the values that differ, and the settings one of them
    leaves out (at the value that does what the code did before the setting existed)."""
    parts = [f"{k} {settings[k]}" for k in sorted(settings) if k in main and settings[k] != main[k]]
    parts += [f"{k} {settings[k]}" for k in sorted(settings) if k not in main]
    gone = sorted(k for k in main if k not in settings)
    if gone:
        parts.append(f"without {', '.join(gone)} (the rule before them)")
    return "; ".join(parts) or "the same values"


def prompt_note(rows: list[dict], marks: dict[str, str]) -> list[str]:
    """A line per mark: how the marked cells' prompt settings differ from the unmarked ones'."""
    if not marks:
        return []
    main = by_share(rows, row_prompts)[0]
    out = []
    for key, mark in marks.items():
        dates = sorted({r["date"] for r in rows if row_prompts(r) == key and r.get("date")})
        when = f" (measured on {', '.join(dates)})" if dates else ""
        if key == UNRECORDED:
            out.append(f"{mark} rows that do not record their prompt settings{when}: summarised before "
                       "the rows kept them.")
        elif main == UNRECORDED:
            out.append(f"{mark} runs under the prompt settings {key}{when}.")
        else:
            out.append(f"{mark} runs under other prompt settings than the unmarked cells{when}: "
                       f"{_difference(json.loads(key), json.loads(main))}.")
    return out
