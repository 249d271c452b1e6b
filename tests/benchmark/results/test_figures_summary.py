"""The README's results table marks the rows whose runs came from other instruction sets."""

from benchmark.results.figures_summary import render_summary_block
from tests.benchmark.results.test_figures import _data


def test_rows_from_another_instruction_set_are_marked_with_a_note():
    data = _data()
    first = data["rows"][0] | {"instruction_sets": ["torch AVX2, numba x86-64-v3"]}
    other = dict(first, format="nerfds", instruction_sets=["torch AVX2, numba x86-64-v3, pinning 2"], date="2026-12-01")
    third = dict(first, format="neu3d")
    data["rows"] = [first, other, third]
    block = render_summary_block(data)
    assert "| HyperNeRF | 0.900 ± 0.010 | 0.910 ± 0.010 | 3 |" in block
    assert "| NeRF-DS | 0.900 ± 0.010† | 0.910 ± 0.010 | 3 |" in block
    assert ("† runs computed with torch AVX2, numba x86-64-v3, pinning 2, on 2026-12-01; the unmarked cells' with "
            "torch AVX2, numba x86-64-v3.") in block


def test_rows_of_one_instruction_set_carry_no_mark():
    block = render_summary_block(_data())
    assert "†" not in block and block.endswith("|\n")
