"""The code passes the linter the project pins (ruff, its rules as pyproject.toml sets them):
an unused import, a name used before it is bound or a closure over a loop variable fails the
suite where it is written, not in a later review."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_code_passes_the_linter():
    pytest.importorskip("ruff", reason="the dev extra's linter is not installed")
    done = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise", str(ROOT)],
                          capture_output=True, text=True, check=False, cwd=ROOT)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-1000:]
