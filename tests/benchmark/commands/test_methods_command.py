"""``trase-bench methods``: every method with where it comes from and one line about it; a
broken plugin is a one-line warning, and the listing still works."""

import json

import pytest

from benchmark.cli import main
from tests.benchmark.methods.plugin_fakes import PLUGIN_MODULE, fake_plugins, methods

BUILT_IN = {"trase", "trase-hard", "trase-all", "cgc", "opengaussian"}


@pytest.fixture
def plugins(monkeypatch, tmp_path):
    yield from fake_plugins(monkeypatch, tmp_path)


def test_builtin_methods_are_listed_without_importing_them(capsys):
    import subprocess
    import sys

    assert main(["methods"]) == 0
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert lines[0] == "methods (trase-bench run --method NAME):"
    rows = {line.split()[0]: line for line in lines[1:] if line.startswith("  ")}
    assert BUILT_IN <= set(rows) and err == ""
    # anything else comes from an installed package (the competitors under competitors/), not built in
    assert all(rows[name].split(None, 2)[1] != "built-in" for name in set(rows) - BUILT_IN)
    assert rows["trase"].split(None, 2)[1:] == ["built-in", "soft-mined contrastive objective (TRASE)"]
    # in a fresh process: the listing imports no method's module (nor torch)
    code = ("import sys; from benchmark.cli import main; main(['methods']); "
            "print(sorted(m for m in sys.modules if m.startswith('benchmark.methods.') or m == 'torch'))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.splitlines()[-1] == "[]"


def test_plugins_are_listed_with_package_and_version_and_broken_ones_warned(plugins, capsys):
    plugins(methods(good="Good", broken="PaperOnly", trase="Good"), package="fake-pkg", version="1.2")
    assert main(["methods"]) == 0
    out, err = capsys.readouterr()
    rows = {line.split()[0]: line.split(None, 1)[1] for line in out.splitlines() if line.startswith("  ")}
    assert set(rows) == BUILT_IN | {"good", "broken"}
    assert rows["good"].split() == ["fake-pkg", "1.2", "A", "fake", "method", "that", "does", "nothing", "useful."]
    assert rows["broken"].split()[:2] == ["fake-pkg", "1.2"] and "cannot be used" in rows["broken"]
    assert rows["trase"].startswith("built-in")
    assert err.splitlines() == [
        (f"warning: method 'trase' (entry point 'trase = {PLUGIN_MODULE}:Good' of package fake-pkg 1.2) is ignored: "
         "a built-in method has that name"),
        (f"warning: method 'broken' (entry point 'broken = {PLUGIN_MODULE}:PaperOnly' of package fake-pkg 1.2): "
         "class PaperOnly declares no 'cpu' preset (every run resolves one of paper, cpu)"),
    ]


def test_json_lists_sources_and_errors(plugins, capsys):
    plugins(methods(good="Good", broken="Missing"))
    assert main(["methods", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data) == {"methods", "warnings"}
    assert data["methods"]["trase"] == {"source": "built-in", "description": "soft-mined contrastive objective (TRASE)",
                                        "package": None, "version": None, "entry_point": None, "error": None}
    assert data["methods"]["good"] == {"source": "fake-pkg 1.2", "description": "A fake method that does nothing useful.",
                                       "package": "fake-pkg", "version": "1.2",
                                       "entry_point": f"good = {PLUGIN_MODULE}:Good", "error": None}
    assert data["methods"]["broken"]["error"] == data["warnings"][0]
    assert data["warnings"][0].startswith("method 'broken' (entry point 'broken = ")


def test_all_lists_objectives_and_mask_generators_too(plugins, capsys):
    plugins({"trase_bench.objectives": {"soft-again": "trase.objectives.soft:SoftMining"},
             "trase_bench.mask_generators": {"nothing": f"{PLUGIN_MODULE}:Generator",
                                             "bad": f"{PLUGIN_MODULE}:not_a_class"}})
    assert main(["methods", "--all", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data) == {"methods", "objectives", "mask_generators", "warnings"}
    assert {"trase", "trase-hard", "cgc", "soft-again"} <= set(data["objectives"])
    assert data["objectives"]["soft-again"]["source"] == "fake-pkg 1.2"
    assert data["mask_generators"]["nothing"]["description"] == "Masks of nothing."
    assert {"sam", "classical", "synthetic"} <= set(data["mask_generators"])
    assert len(data["warnings"]) == 1 and data["warnings"][0].startswith("mask generator 'bad' (entry point")
    assert main(["methods", "--all"]) == 0
    out = capsys.readouterr().out
    assert "objectives (--set method.features.objective=NAME):" in out
    assert "mask generators (--set masks.generator=NAME):" in out
