"""``make demo`` gives a newcomer the recorded figures on any machine, and the README quotes them
(golden_demo.py: how they were recorded and on which machines)."""

import re
from pathlib import Path

import pytest

from tests.benchmark.golden_demo import DEMO, differences, measure, recording

ROOT = Path(__file__).resolve().parents[2]


def test_the_readme_and_the_quickstart_quote_the_recorded_demo_line():
    line = recording()["figures"]["line"]
    for page in ("README.md", "docs/quickstart.md"):
        assert line in (ROOT / page).read_text(), f"{page} does not show the demo's recorded line: {line}"


def test_the_pages_name_the_demo_runs_folder_as_the_recording_does():
    name = re.search(r"runs/trase/hypernerf/synthetic/(c[0-9a-f]{8})/", recording()["figures"]["line"]).group(1)
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]  # user pages; notes keep their history
    stale = {f"{p.name}: {n}" for p in pages for n in re.findall(r"runs/trase/hypernerf/synthetic/(c[0-9a-f]{8})\b",
                                                               p.read_text()) if n != name}
    assert not stale, f"the demo's run is {name}; pages name another: {sorted(stale)}"


def test_the_recording_is_of_the_makefiles_demo_run():
    demo = re.search(r"^demo:.*\n\t\$\(VENV\)/bin/trase-bench (.+)$", (ROOT / "Makefile").read_text(), re.MULTILINE)
    assert demo and demo.group(1).split() == DEMO


@pytest.mark.slow
def test_a_fresh_demo_run_gives_the_recorded_figures_bit_for_bit(tmp_path):
    golden = recording()
    diff = differences(golden["figures"], measure(tmp_path))
    assert not diff, f"make demo differs from its recording (reproduced on {len(golden['machines'])} machine(s)): {diff}"


def test_the_quickstarts_stage_seconds_are_the_recorded_runs():
    seconds = recording()["machines"][0]["stage_seconds"]
    text = " ".join((ROOT / "docs" / "quickstart.md").read_text().split())
    for stage, said in (("geometry", "geometry"), ("features", "features"), ("fit", "clustering (fit)"),
                        ("evaluate", "evaluate")):
        assert f"{said} {round(seconds[stage])} s" in text, f"docs/quickstart.md: {stage} took {seconds[stage]:.0f} s"
