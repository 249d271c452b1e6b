"""Figures rows measured under other prompt settings than the rest are marked on the page."""

from benchmark.results.figures_methods import render_methods_block
from benchmark.results.figures_prompts import UNRECORDED, prompt_marks, prompt_note, row_prompts, run_prompt_settings
from tests.benchmark.results.test_figures import _methods_data

RETRIES = {"rule": "gt-first-appearance", "corrections": 3, "correction_undone_radius": 2.0, "correction_region_tries": 2}
BEFORE = {"rule": "gt-first-appearance", "corrections": 3}  # the retry settings left out: the rule before them


def _rows(*settings):
    return [({"date": f"2026-11-{28 + i}"} | ({"prompts": s} if s is not None else {})) for i, s in enumerate(settings)]


def test_a_runs_prompt_settings_are_its_recorded_config_section():
    assert run_prompt_settings({"config": {"prompts": RETRIES}}) == RETRIES
    assert run_prompt_settings({"config": {}}) == {}
    assert row_prompts({}) == UNRECORDED and row_prompts({"prompts": BEFORE}) != row_prompts({"prompts": RETRIES})


def test_one_setting_marks_nothing():
    rows = _rows(RETRIES, RETRIES)
    assert prompt_marks(rows) == {} and prompt_note(rows, {}) == []


def test_the_minority_is_marked_with_how_it_differs():
    rows = _rows(RETRIES, RETRIES, BEFORE)
    marks = prompt_marks(rows)
    assert marks == {row_prompts(rows[2]): "ᵃ"}
    (line,) = prompt_note(rows, marks)
    assert line == ("ᵃ runs under other prompt settings than the unmarked cells (measured on 2026-11-30): without "
                    "correction_region_tries, correction_undone_radius (the rule before them).")
    rows = _rows(RETRIES, RETRIES, dict(RETRIES, corrections=5))
    assert prompt_note(rows, prompt_marks(rows))[0].endswith(": corrections 5.")


def test_rows_without_settings_are_marked_as_unrecorded():
    rows = _rows(RETRIES, RETRIES, None)
    (line,) = prompt_note(rows, prompt_marks(rows))
    assert line.startswith("ᵃ rows that do not record their prompt settings (measured on 2026-11-30)")


def test_the_methods_table_marks_the_cells_and_their_clicks():
    data = _methods_data()
    for r in data["rows"]:
        r["prompts"] = BEFORE if r["method"] == "cgc" else RETRIES
    block = render_methods_block(data)
    assert "| cgc | 0.700 (1)ᵃ | 0.700 (1)ᵃ |" in block and "| trase | 0.900 ± 0.010 | 0.900 ± 0.010 |" in block
    clicks = block.split("**Clicks, reconstructed geometry**")[1]
    assert "| cgc | 0.600 ± 0.200; 3.0 ± 0.0 / 4.0 ± 1.0ᵃ |" in clicks
    assert "ᵃ runs under other prompt settings than the unmarked cells" in block
    for r in data["rows"]:
        r["prompts"] = RETRIES
    assert "ᵃ" not in render_methods_block(data)
