"""The run settings as recorded before their redesign, on any machine: every resolved config
and its protocol label, and the golden cases' stage keys (golden_portable.py)."""

import json

from tests.benchmark import golden_portable as gp


def test_every_resolved_config_and_protocol_label_is_as_recorded():
    want = json.loads(gp.GOLDEN.read_text())["configs"]
    got = gp.resolved_configs()
    assert set(got) == set(want)
    diff = {k: (want[k], got[k]) for k in want if got[k] != want[k]}
    assert not diff, f"{len(diff)} configs differ from the recording, e.g. {dict(list(diff.items())[:3])}"


def test_the_golden_cases_stage_keys_are_as_recorded():
    assert gp.stage_keys() == json.loads(gp.GOLDEN.read_text())["stage_keys"]
