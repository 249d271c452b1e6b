"""The README and docs/ say only what the code has: their links resolve, the library guide's
imports run, and the README's results table is the rendering of the figures data."""

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
# pages the docs build writes (mkdocs-gen-files, scripts/docs_settings.py), linked before they exist
GENERATED = {ROOT / "docs" / "reference" / "settings.md"}


def test_relative_links_resolve():
    broken = []
    for page in PAGES:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
            if "://" in target or target.startswith("mailto:"):
                continue
            path = (page.parent / target).resolve()
            if not path.exists() and path not in GENERATED:
                broken.append(f"{page.relative_to(ROOT)} -> {target}")
    assert not broken, broken


def test_the_settings_guides_excerpt_is_what_the_presets_command_prints(capsys):
    """docs/settings.md quotes `trase-bench presets --preset cpu --dataset neu3d`, file and line
    of each value included: a move in the preset tables must move the quote too."""
    from benchmark.cli import main

    text = (ROOT / "docs" / "settings.md").read_text()
    excerpt = re.search(r"An excerpt of the second.*?```text\n(.*?)```", text, flags=re.DOTALL)
    assert excerpt, "the settings guide's excerpt is missing"
    assert main(["presets", "--preset", "cpu", "--dataset", "neu3d"]) == 0
    printed = set(capsys.readouterr().out.splitlines())
    quoted = excerpt.group(1).splitlines()
    assert quoted and not [line for line in quoted if line not in printed]


def test_the_library_guides_imports_run():
    text = (ROOT / "docs" / "library.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    assert blocks, "the library guide's code is missing"
    for block in blocks:
        imports = "\n".join(line.split("#")[0] for line in block.splitlines() if line.startswith("from "))
        exec(compile(imports, "docs/library.md", "exec"), {})  # noqa: S102 - the guide's own imports


def _summary():
    from benchmark.results.figures_summary import SUMMARY_BEGIN, SUMMARY_END, render_summary_block

    data = json.loads((ROOT / "docs" / "figures.json").read_text())
    return (SUMMARY_BEGIN, SUMMARY_END), render_summary_block(data), "trase-bench figures --from-data --write-page README.md"


def _performance():
    from benchmark.results.perf_page import PERF_BEGIN, PERF_END, render_perf_block

    data = json.loads((ROOT / "docs" / "perf-runs" / "current.json").read_text())
    return ((PERF_BEGIN, PERF_END), render_perf_block(data),
            "trase-bench perf --json docs/perf-runs/current.json --from-json --write-page docs/performance.md")


def _skip():
    from benchmark.perf.skip_page import SKIP_BEGIN, SKIP_END, render_skip_block

    data = json.loads((ROOT / "docs" / "skip-runs" / "current.json").read_text())
    return ((SKIP_BEGIN, SKIP_END), render_skip_block(data),
            "trase-bench perf skip --json docs/skip-runs/current.json --from-json --write-page docs/skip.md")


def _results_file():
    from benchmark.results.fields import FIELDS_BEGIN, FIELDS_END, render_fields_block

    return ((FIELDS_BEGIN, FIELDS_END), render_fields_block(),
            "python -m benchmark.results.fields docs/reference/results-file.md")


@pytest.mark.parametrize(("page", "expected"), [("README.md", _summary), ("docs/performance.md", _performance),
                                                ("docs/skip.md", _skip),
                                                ("docs/reference/results-file.md", _results_file)])
def test_each_generated_block_is_the_rendering_of_its_data(page, expected):
    from benchmark.results.figures import page_block

    markers, rendered, command = expected()
    assert page_block((ROOT / page).read_text(), page, markers) == rendered, f"{page}: run {command}"


def test_the_readme_is_short():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 130
