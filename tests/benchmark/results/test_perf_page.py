"""The performance page's figures block, rendered from a perf JSON file."""

import json

import pytest

from benchmark.errors import UserError
from benchmark.results.perf_page import PERF_BEGIN, PERF_END, render_perf_block, write_perf_page


def _m(x):
    return {"median": x, "spread": 0.0, "all": [x]}


DATA = {
    "machine": {"cpu_count": 2, "cpu": "AMD EPYC", "torch_threads": 2,
                "numerics": {"mode": "portable", "avx512": ["avx512f"]}},
    "started": "2026-11-29T18:00:00",
    "suites": {
        "raster": {"quick": False, "settings": [
            {"gaussians": 20000, "width": 256, "height": 192, "channels": 35, "numba": {"total_s": _m(0.024)},
             "torch": {"total_s": _m(0.675)}, "speedup": {"total_s": 28.1}}]},
        "knn": {"quick": False, "sizes": [{"n": 1000000, "methods": {
            "trase.smoothing.knn_indices (cKDTree, 1 thread)": {"seconds": _m(31.5)},
            "sklearn NearestNeighbors kd_tree n_jobs=-1": {"seconds": _m(64.0)}}}]},
        "gpu": {"skipped": "no CUDA device"},
    },
}


def test_rows_carry_medians_ratios_and_the_machine():
    block = render_perf_block(DATA)
    assert block.splitlines()[0] == ("Machine: 2 cores, AMD EPYC (AVX-512), portable numerics, torch threads 2; "
                                     "measured 2026-11-29.")
    assert ("| rasterizer, 20,000 gaussians, 256x192, 35 channels, forward + backward | numba 24.0 ms, torch "
            "reference 675.0 ms (28.1x) |") in block
    assert ("| K=16 neighbours, 1,000,000 gaussians | cKDTree, 1 thread (trase) 31.50 s; sklearn NearestNeighbors "
            "kd_tree n_jobs=-1 64.00 s |") in block


def test_the_machine_names_the_pinning_of_portable_bits_from_the_second_on():
    from benchmark.results.perf_page import machine_line

    pinned = {**DATA, "machine": {**DATA["machine"], "numerics": {"mode": "portable", "pinning": 3}}}
    assert "(AVX2), portable numerics pinning 3, torch threads 2" in machine_line(pinned)
    first = {**DATA, "machine": {**DATA["machine"], "numerics": {"mode": "portable", "pinning": 1}}}
    assert "portable numerics, torch" in machine_line(first)
    native = {**DATA, "machine": {**DATA["machine"], "numerics": {"mode": "native", "pinning": 3}}}
    assert "native numerics, torch" in machine_line(native)


def test_the_page_block_is_replaced_and_a_page_without_one_refused(tmp_path):
    data = tmp_path / "perf.json"
    data.write_text(json.dumps(DATA))
    page = tmp_path / "page.md"
    page.write_text(f"# Perf\n\n{PERF_BEGIN}\nold\n{PERF_END}\n\nafter\n")
    write_perf_page(page, data)
    text = page.read_text()
    assert "old" not in text and text.endswith(f"{PERF_END}\n\nafter\n") and "numba 24.0 ms" in text
    page.write_text("# no block\n")
    with pytest.raises(UserError, match="page.md: no generated figures block"):
        write_perf_page(page, data)
    page.write_text(f"{PERF_BEGIN}\n{PERF_BEGIN}\n{PERF_END}\n")
    with pytest.raises(UserError, match="page.md: needs exactly one figures block"):
        write_perf_page(page, data)
    page.write_text(f"{PERF_BEGIN}\n{PERF_END}\n")
    data.write_text("{")
    with pytest.raises(UserError, match="perf.json: not a readable perf JSON file"):
        write_perf_page(page, data)
    with pytest.raises(UserError, match="holds none of the suites"):
        render_perf_block({"machine": {}, "suites": {"gpu": {"skipped": "no GPU"}}})


def test_the_command_writes_a_page_from_a_file_and_says_what_it_needs(tmp_path, capsys):
    from benchmark.cli import main

    data = tmp_path / "perf.json"
    data.write_text(json.dumps(DATA))
    page = tmp_path / "page.md"
    page.write_text(f"{PERF_BEGIN}\n{PERF_END}\n")
    assert main(["perf", "--json", str(data), "--from-json", "--write-page", str(page)]) == 0
    assert "numba 24.0 ms" in page.read_text()
    assert main(["perf", "--from-json", "--write-page", str(page)]) != 0
    assert "--write-page renders a --json file: give --json FILE" in capsys.readouterr().err
