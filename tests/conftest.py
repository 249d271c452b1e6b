"""Suite-wide pytest setup: hypothesis profiles for the property-based stress tests.

Profiles (``hypothesis.settings``):

* ``ci`` (default): few examples per property, no deadline, derandomised, so the whole
  suite stays fast and deterministic on a small shared CI machine.
* ``deep``: many examples per property and a fresh random seed each run, for a long
  search before a release: ``pytest tests/stress --deep`` (or ``--hypothesis-profile=deep``).
  ``--deep`` also runs the tests marked ``deep`` (minutes each; skipped by default).
"""

from __future__ import annotations

import os
import sys

from benchmark import numerics

# the default numeric mode, in place before any test imports numpy, torch or numba (as the
# command line does): in-process runs compute as `trase-bench` does
numerics.apply(numerics.DEFAULT)

# no kernel compilation beside scene generation in tests (benchmark.background_compile): its
# own tests turn it on
os.environ.setdefault("TRASE_PRECOMPILE", "0")

try:  # hypothesis is a dev dependency; the rest of the suite runs without it
    from hypothesis import HealthCheck, settings
except ImportError:  # pragma: no cover
    settings = None

if settings is not None:
    _common = {
        "deadline": None,  # shared 2-core machines: timing varies too much for per-example deadlines
        "suppress_health_check": [HealthCheck.too_slow, HealthCheck.data_too_large],
        "print_blob": True,  # a failure prints the blob to reproduce it with @reproduce_failure
    }
    settings.register_profile("ci", max_examples=12, derandomize=True, **_common)
    settings.register_profile("deep", max_examples=400, derandomize=False, **_common)
    settings.load_profile("ci")


def pytest_addoption(parser):
    parser.addoption(
        "--deep",
        action="store_true",
        default=False,
        help="stress tests: use the 'deep' hypothesis profile (many examples, random seeds)",
    )


def pytest_configure(config):
    config.addinivalue_line("markers", "deep: long stress tests, run only with --deep")
    if settings is not None and config.getoption("--deep", default=False):
        settings.load_profile("deep")


def pytest_collection_modifyitems(config, items):
    """Tests marked ``deep`` (minutes each) are skipped unless --deep is given."""
    if config.getoption("--deep", default=False):
        return
    import pytest

    skip = pytest.mark.skip(reason="long stress test; run with --deep")
    for item in items:
        if "deep" in item.keywords:
            item.add_marker(skip)


def pytest_terminal_summary(terminalreporter):
    """One line of stress counts (cases tried, corruptions caught, kills survived), summed
    over the ``STATS`` dicts of the stress test modules that ran."""
    totals: dict[str, int] = {}
    for name, mod in list(sys.modules.items()):
        if "stress" in name.split(".") and name.split(".")[-1].startswith("test_"):
            for k, v in getattr(mod, "STATS", {}).items():
                if isinstance(v, int):
                    totals[k] = totals.get(k, 0) + v
    if any(totals.values()):
        terminalreporter.write_line("stress counts: " + ", ".join(f"{k} {v}" for k, v in sorted(totals.items())))
