"""``trase-bench run`` gives the results recorded before the benchmark layer's redesign, bit for
bit (tests/benchmark/golden_pipeline.py: the cases, and how to re-record)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.benchmark.golden_pipeline import GOLDEN, machine_isa

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_run_results_match_the_recording(tmp_path):
    golden = json.loads(GOLDEN.read_text())
    if golden["machine"] != machine_isa():
        pytest.skip(f"recorded on {golden['machine']}, this machine {machine_isa()}: feature and geometry "
                    "bits depend on the instruction set (docs/determinism.md)")
    # a fresh process: feature bits depend on what ran earlier in the process (docs/determinism.md)
    out = tmp_path / "now.json"
    subprocess.run([sys.executable, "-m", "tests.benchmark.golden_pipeline", "--json", str(out)], cwd=ROOT,
                   check=True, capture_output=True, timeout=600)
    now = json.loads(out.read_text())["cases"]
    assert set(now) == set(golden["cases"])
    for case, want in golden["cases"].items():
        got = now[case]
        diff = {k: (want[k], got.get(k)) for k in want if got.get(k) != want[k]}
        assert not diff, f"{case}: differs from the recording: {diff}"
