"""``trase-bench perf methods``: the names it is given are checked before any run."""

from benchmark.cli import main


def test_unknown_method_is_one_line_before_any_run(capsys):
    assert main(["perf", "methods", "--method", "trase", "--method", "no-such-method"]) != 0
    err = capsys.readouterr().err
    assert "no-such-method" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_the_measured_run_pins_the_render_path_by_an_override():
    from benchmark.perf.methods import _overrides

    assert _overrides(5) == ["geometry.source=ground-truth", "method.features.iterations=5", "prompts.click_sets=1"]
    assert _overrides(5, True)[-1] == "method.features.fastpath=true"
