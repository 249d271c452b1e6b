"""``trase-bench run`` gives the recorded results: bit for bit in the default (portable) numerics
on every machine, within a tolerance in native numerics (golden_pipeline.py: the cases, the
machines that reproduced them, and how to re-record)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.benchmark.golden_pipeline import CASES, recording
from tests.benchmark.golden_portable import CEILING_TOLERANCE, GT_TOLERANCE, gt_cases

ROOT = Path(__file__).resolve().parents[2]


def _measure(out: Path, *extra: str) -> dict:
    # a fresh process: the numeric mode is chosen before the libraries load
    subprocess.run([sys.executable, "-m", "tests.benchmark.golden_pipeline", "--json", str(out), *extra], cwd=ROOT,
                   check=True, capture_output=True, timeout=600)
    return json.loads(out.read_text())["cases"]


@pytest.mark.slow
def test_run_results_match_the_recording_bit_for_bit_on_any_machine(tmp_path):
    golden = recording()
    measured = _measure(tmp_path / "now.json")
    assert set(measured) == set(golden["cases"])
    for case, want in golden["cases"].items():
        got = measured[case]
        diff = {k: (want[k], got.get(k)) for k in want if got.get(k) != want[k]}
        assert not diff, (f"{case}: differs from the recording (reproduced on {len(golden['machines'])} machine(s), "
                          f"e.g. {golden['machines'][0]}): {diff}")


@pytest.mark.slow
def test_native_numerics_stay_within_a_tolerance_of_the_recording(tmp_path):
    """Native kernels round otherwise: the ground-truth-geometry cases (no reconstruction to
    amplify a last bit) stay close; a broken stage moves them by tenths."""
    want = gt_cases(recording()["cases"])
    got = gt_cases(_measure(tmp_path / "native.json", "--numerics", "native", "--cases", *want))
    assert set(got) == set(want) and set(want) < set(CASES)
    for case, fields in want.items():
        for k, v in fields.items():
            if isinstance(v, int):
                assert got[case][k] == v, (case, k)
            else:
                tolerance = CEILING_TOLERANCE if k == "ceiling_miou" else GT_TOLERANCE
                assert got[case][k] == pytest.approx(v, abs=tolerance), (case, k)
