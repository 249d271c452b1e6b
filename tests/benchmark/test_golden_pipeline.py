"""``trase-bench run`` gives the results recorded before the redesigns: within a tolerance on
every machine for the ground-truth-geometry cases (golden_portable.py), bit for bit where a
recording of this machine's instruction sets exists (golden_pipeline.py: the cases, and how to
re-record)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.benchmark.golden_pipeline import machine_isa, recordings
from tests.benchmark.golden_portable import CEILING_TOLERANCE, GT_TOLERANCE, gt_cases
from tests.benchmark.golden_portable import GOLDEN as PORTABLE

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def measured(tmp_path_factory) -> dict:
    # a fresh process: feature bits depend on what ran earlier in the process (docs/determinism.md)
    out = tmp_path_factory.mktemp("golden") / "now.json"
    subprocess.run([sys.executable, "-m", "tests.benchmark.golden_pipeline", "--json", str(out)], cwd=ROOT,
                   check=True, capture_output=True, timeout=600)
    return json.loads(out.read_text())["cases"]


@pytest.mark.slow
def test_ground_truth_cases_match_the_recording_on_any_machine(measured):
    want = json.loads(PORTABLE.read_text())["gt_cases"]
    got = gt_cases(measured)
    assert set(got) == set(want)
    for case, fields in want.items():
        for k, v in fields.items():
            if isinstance(v, int):
                assert got[case][k] == v, (case, k)
            else:
                tolerance = CEILING_TOLERANCE if k == "ceiling_miou" else GT_TOLERANCE
                assert got[case][k] == pytest.approx(v, abs=tolerance), (case, k)


@pytest.mark.slow
def test_run_results_match_the_recording_bit_for_bit(measured):
    here = [r for r in recordings() if r["machine"] == machine_isa()]
    if not here:
        pytest.skip(f"no recording for {machine_isa()} (recorded: {[r['machine'] for r in recordings()]}): feature "
                    "and geometry bits depend on the instruction set (docs/determinism.md)")
    (golden,) = here
    assert set(measured) == set(golden["cases"])
    for case, want in golden["cases"].items():
        got = measured[case]
        diff = {k: (want[k], got.get(k)) for k in want if got.get(k) != want[k]}
        assert not diff, f"{case}: differs from the recording: {diff}"
