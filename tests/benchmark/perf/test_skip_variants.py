"""``perf skip --variant``: a subset of the suite's variants, in the suite's order."""

import pytest

from benchmark.errors import UserError
from benchmark.perf.skip import STATIC_THRESHOLD, variants


def test_every_variant_by_default_and_a_subset_in_the_suites_order():
    every = variants(STATIC_THRESHOLD)
    assert list(every) == ["full", "static", "converged", "resolution", "resolution+primitives", "primitives"]
    assert "geometry.train.primitive_schedule=frequency" in every["primitives"]
    assert not any("resolution_schedule" in o for o in every["primitives"])
    some = variants(STATIC_THRESHOLD, names=["resolution+primitives", "full"])
    assert list(some) == ["full", "resolution+primitives"] and some["full"] == every["full"]


def test_an_unknown_variant_is_named():
    with pytest.raises(UserError, match="unknown skip variant.*fast.*the suite's: full, static"):
        variants(STATIC_THRESHOLD, names=["full", "fast"])


def test_the_option_reaches_the_suite_and_only_a_suite_with_variants(tmp_path, monkeypatch, capsys):
    import benchmark.commands.perf as perf_command
    from benchmark.cli import main

    seen = {}

    def fake_skip(quick, echo, variant_names=None, out_dir=None):
        seen.update(variant_names=variant_names)
        return {}

    monkeypatch.setattr(perf_command, "get_suite", lambda name: fake_skip)
    assert main(["perf", "skip", "--variant", "full", "--variant", "resolution", "--out-dir", str(tmp_path)]) == 0
    assert seen == {"variant_names": ["full", "resolution"]}
    monkeypatch.undo()
    assert main(["perf", "knn", "--variant", "full"]) != 0
    assert "--variant: none of knn measures variants" in capsys.readouterr().err
    assert main(["perf", "skip", "--quick", "--variant", "fast", "--out-dir", str(tmp_path)]) == 1
    assert "error: unknown skip variant(s) fast" in capsys.readouterr().err
