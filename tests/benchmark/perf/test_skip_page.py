"""The skip page's figures block, rendered from a ``perf skip --json`` file."""

import json

import pytest

from benchmark.errors import UserError
from benchmark.perf.skip_page import SKIP_BEGIN, SKIP_END, render_skip_block
from benchmark.results.perf_page import write_perf_page


def _run(variant, geometry, features, miou, stopping=None):
    return {"dataset": "hypernerf", "variant": variant, "overrides": [], "stopping": stopping or {},
            "seconds": {"geometry": geometry, "features": features}, "gaussians": 1000, "static_gaussians": 0,
            "test_psnr": 28.5, "ceiling": 0.88, "ceiling_moving_frames": 0.87, "ceiling_other_frames": 0.89,
            "miou": miou, "metric": "official-v2"}


DATA = {
    "machine": {"cpu_count": 2, "cpu": "AMD EPYC", "torch_threads": 2, "numerics": {"mode": "portable"}},
    "started": "2026-11-29T20:00:00",
    "suites": {"skip": {"quick": False, "settings": {"sequence": "synthetic", "overrides": []}, "runs": [
        _run("full", 200.0, 100.0, 0.87),
        _run("converged", 150.0, 25.0, 0.86, {"features": {"stopped_at": 750, "cap": 3000}}),
        {"dataset": "hypernerf", "variant": "static", "error": "RuntimeError: out of memory"}]}},
}


def test_the_block_has_the_machine_the_runs_and_their_ratios_to_the_full_schedule():
    block = render_skip_block(DATA)
    lines = block.splitlines()
    assert lines[0] == "Machine: 2 cores, AMD EPYC (AVX2), portable numerics, torch threads 2; measured 2026-11-29."
    assert lines[4].startswith("| format | variant | geometry s | features s |")
    assert "| hypernerf | converged | 150 | 25 | 28.50 | 0% | 0.8800 | 0.8700 | 0.8900 | 0.8600 | features 750/3000 " \
           "| 0.75 | 0.25 |" in lines
    assert any(line.startswith("| hypernerf | static | FAILED |") for line in lines)


def test_a_skip_page_gets_its_block_and_a_file_without_the_suite_is_refused(tmp_path):
    data, page = tmp_path / "skip.json", tmp_path / "skip.md"
    data.write_text(json.dumps(DATA))
    page.write_text(f"# Skip\n\n{SKIP_BEGIN}\nold\n{SKIP_END}\nafter\n")
    write_perf_page(page, data, {(SKIP_BEGIN, SKIP_END): render_skip_block})
    text = page.read_text()
    assert "old" not in text and "| hypernerf | full | 200 | 100 |" in text and text.endswith(f"{SKIP_END}\nafter\n")
    with pytest.raises(UserError, match="holds no skip suite"):
        render_skip_block({"machine": {}, "suites": {"raster": {}}})


def test_the_perf_command_writes_the_skip_page(tmp_path):
    from benchmark.cli import main

    data, page = tmp_path / "skip.json", tmp_path / "skip.md"
    data.write_text(json.dumps(DATA))
    page.write_text(f"{SKIP_BEGIN}\n{SKIP_END}\n")
    assert main(["perf", "--json", str(data), "--from-json", "--write-page", str(page)]) == 0
    assert "| hypernerf | full | 200 | 100 |" in page.read_text()


def test_the_training_views_ceiling_is_a_column_where_the_runs_have_it():
    with_it = {**_run("full", 200.0, 100.0, 0.87), "ceiling_training_views": 0.9123}
    suite = {**DATA, "suites": {"skip": {**DATA["suites"]["skip"], "runs": [with_it]}}}
    lines = render_skip_block(suite).splitlines()
    assert "| ceiling | ceiling, training views | ceiling, frames with motion |" in lines[4]
    assert "| hypernerf | full | 200 | 100 | 28.50 | 0% | 0.8800 | 0.9123 | 0.8700 | 0.8900 | 0.8700 |" in "\n".join(lines)
    assert "training views" not in render_skip_block(DATA)  # suites measured before it existed
