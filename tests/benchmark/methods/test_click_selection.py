"""Click polarity at the benchmark's edges: the prompts file keeps a negative click's polarity,
a method that declares no negative clicks takes positive ones only, and one that does without a
click selection of its own gets the benchmark's rule for clusters."""

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


def test_a_method_declaring_negative_clicks_has_them_remove_and_keep_out_its_clusters():
    import types

    from benchmark.methods import click_selection

    method = types.SimpleNamespace(name="sets", negative_clicks=True, click_clusters=lambda f, s, p: [2, 5, 2, 5, 7])
    polarity = [True, True, False, True, True]  # +2 +5 -2 then +5 again, +7
    prompts = types.SimpleNamespace(clicks=[Click(i, i, positive=p) for i, p in enumerate(polarity)])
    assert click_selection(method, None, None, prompts) == ([5, 7], [2, 5, 2, 5, 7])
    polarity = [True, False, True]  # -5 before +5: kept out
    prompts.clicks = [Click(i, i, positive=p) for i, p in enumerate(polarity)]
    method.click_clusters = lambda f, s, p: [2, 5, 5]
    assert click_selection(method, None, None, prompts)[0] == [2]


def test_a_method_with_its_own_click_selection_and_no_declaration_takes_negative_clicks():
    import types

    from benchmark.methods import takes_negative_clicks

    assert takes_negative_clicks(types.SimpleNamespace(click_selection=lambda *a: ([], [])))
    assert not takes_negative_clicks(types.SimpleNamespace(click_selection=lambda *a: ([], []), negative_clicks=False))
    assert not takes_negative_clicks(types.SimpleNamespace())
