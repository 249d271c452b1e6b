"""What ``make demo`` gives a newcomer: its run on a fresh machine (no caches, the synthetic scene
generated anew) in the default (portable) numerics, recorded once for every machine. The README
quotes the recorded run line; tests check both, so neither can drift from the code.

    python -m tests.benchmark.golden_demo --write     # re-record after an intended change
    python -m tests.benchmark.golden_demo --confirm   # add this machine to those that reproduced it
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
GOLDEN = Path(__file__).with_name("golden") / "demo.json"
DEMO = ["run", "--method", "trase", "--dataset", "hypernerf", "--runs", "runs"]  # the Makefile's demo run


def measure(work: Path) -> dict:
    """The demo run in ``work`` (its runs/ and scene cache there), as a fresh shell runs it: no
    numeric environment inherited -> the compared figures and the printed run line."""
    from benchmark import numerics
    from benchmark.results import load_results
    from tests.benchmark.golden_pipeline import picked

    drop = {numerics.ENV_MODE, *numerics.PORTABLE_ENV}
    env = {k: v for k, v in os.environ.items() if k not in drop} | {"TRASE_BENCH_CACHE": str(work / "cache"),
                                                                    "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "benchmark.cli", *DEMO], cwd=work, env=env, capture_output=True,
                          text=True, timeout=3600, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"make demo's run failed:\n{proc.stderr[-3000:]}")
    (line,) = [ln for ln in proc.stdout.splitlines() if ln.startswith("trase hypernerf/")]
    (path,) = (work / "runs").glob("trase/hypernerf/synthetic/*/results.json")
    r = load_results(path)
    return {"line": line, **picked(r), "stage_seconds": {k: v["seconds"] for k, v in r["stages"].items()}}


def recording() -> dict:
    """{"numerics", "figures", "machines"}: the figures one machine measured, and every machine
    (with the seconds its stages took) that reproduced them."""
    return json.loads(GOLDEN.read_text())


def differences(want: dict, got: dict) -> dict:
    """The recorded figures a measurement does not reproduce (the seconds aside)."""
    return {k: (want[k], got.get(k)) for k in want if got.get(k) != want[k]}


def main(argv=None) -> int:
    from tests.benchmark.golden_pipeline import machine

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help=f"record into {GOLDEN} (replaces the recording)")
    ap.add_argument("--confirm", action="store_true", help="add this machine to the recording's machines "
                    "(only when it reproduces the figures bit for bit)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        got = measure(Path(tmp))
    here = machine() | {"stage_seconds": got.pop("stage_seconds")}
    if args.confirm:
        golden = recording()
        diff = differences(golden["figures"], got)
        if diff:
            raise SystemExit(f"this machine does not reproduce the recording: {diff}")
        golden["machines"] = [m for m in golden["machines"] if m["host_cpu"] != here["host_cpu"]] + [here]
        GOLDEN.write_text(json.dumps(golden, indent=1, sort_keys=True) + "\n")
    elif args.write:
        record = {"numerics": "portable", "figures": got, "machines": [here]}
        GOLDEN.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    print(json.dumps({"figures": got, "machine": here}, indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
