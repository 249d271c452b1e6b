"""Click polarity at the benchmark's edges: the prompts file keeps a negative click's polarity,
and a method without its own click selection takes positive clicks only."""

import pytest

from trase.prompts import Click, PromptError


def test_the_prompts_file_holds_a_negative_clicks_polarity_and_positive_files_are_unchanged():
    import json

    from benchmark.protocol.prompts import BenchmarkPrompts

    clicks = [Click(3.5, 4.5, "v0", 0.0, 0), Click(5.5, 6.5, "v0", 0.0, 0, positive=False)]
    bp = BenchmarkPrompts(0, "v0", 0.0, clicks, "test")
    d = json.loads(json.dumps(bp.to_dict()))
    assert "positive" not in d["clicks"][0] and d["clicks"][1]["positive"] is False
    assert BenchmarkPrompts.from_dict(d).clicks == clicks
    d["clicks"][1]["positive"] = "no"
    with pytest.raises(PromptError, match="malformed prompts file .*positive is true or false"):
        BenchmarkPrompts.from_dict(d)


def test_a_method_without_click_selection_takes_positive_clicks_only():
    import types

    from benchmark.methods import MethodError, click_selection

    method = types.SimpleNamespace(name="plain", click_clusters=lambda f, s, p: [2, -1, 2])
    prompts = types.SimpleNamespace(clicks=[Click(0, 0), Click(1, 1), Click(2, 2)])
    assert click_selection(method, None, None, prompts) == ([2], [2, -1, 2])
    prompts.clicks[1] = Click(1, 1, positive=False)
    with pytest.raises(MethodError, match="'plain' takes positive clicks only"):
        click_selection(method, None, None, prompts)
