"""The README and docs/ say only what the code has: their links resolve, the library guide's
imports run, and the README's results table is the rendering of the figures data."""

import json
import re
from pathlib import Path

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


def test_the_library_guides_imports_run():
    text = (ROOT / "docs" / "library.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "the library guide's code is missing"
    for block in blocks:
        imports = "\n".join(line.split("#")[0] for line in block.splitlines() if line.startswith("from "))
        exec(compile(imports, "docs/library.md", "exec"), {})


def test_the_readmes_results_table_is_the_rendering_of_the_figures_data():
    from benchmark.results.figures import page_block
    from benchmark.results.figures_summary import SUMMARY_BEGIN, SUMMARY_END, render_summary_block

    data = json.loads((ROOT / "docs" / "figures.json").read_text())
    block = page_block((ROOT / "README.md").read_text(), "README.md", (SUMMARY_BEGIN, SUMMARY_END))
    assert block == render_summary_block(data), "README.md: run trase-bench figures --from-data --write-page README.md"


def test_the_performance_pages_figures_are_the_rendering_of_its_perf_data():
    from benchmark.results.figures import page_block
    from benchmark.results.perf_page import PERF_BEGIN, PERF_END, render_perf_block

    data = json.loads((ROOT / "docs" / "perf-runs" / "current.json").read_text())
    block = page_block((ROOT / "docs" / "performance.md").read_text(), "docs/performance.md", (PERF_BEGIN, PERF_END))
    assert block == render_perf_block(data), ("docs/performance.md: run trase-bench perf --json "
                                              "docs/perf-runs/current.json --from-json --write-page docs/performance.md")


def test_the_readme_is_short():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 130


def test_the_skip_pages_figures_are_the_rendering_of_its_perf_data():
    from benchmark.results.figures import page_block
    from benchmark.perf.skip_page import SKIP_BEGIN, SKIP_END, render_skip_block

    data = json.loads((ROOT / "docs" / "skip-runs" / "current.json").read_text())
    block = page_block((ROOT / "docs" / "skip.md").read_text(), "docs/skip.md", (SKIP_BEGIN, SKIP_END))
    assert block == render_skip_block(data), ("docs/skip.md: run trase-bench perf skip --json "
                                              "docs/skip-runs/current.json --from-json --write-page docs/skip.md")


def test_the_results_file_reference_is_the_rendering_of_its_fields():
    from benchmark.results.fields import FIELDS_BEGIN, FIELDS_END, render_fields_block
    from benchmark.results.figures import page_block

    page = ROOT / "docs" / "reference" / "results-file.md"
    block = page_block(page.read_text(), str(page), (FIELDS_BEGIN, FIELDS_END))
    assert block == render_fields_block(), "run python -m benchmark.results.fields docs/reference/results-file.md"
