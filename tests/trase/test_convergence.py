import math
from types import SimpleNamespace

import pytest

from trase.convergence import Plateau, StopRule, held_out_indices, read_summary, write_summary


def _views(n):
    # names out of time order: the rule holds out by time
    return [SimpleNamespace(name=f"v{(7 * i) % n:02d}", camera=SimpleNamespace(time=((7 * i) % n) / n))
            for i in range(n)]


def test_held_out_views_are_spread_over_time_and_never_the_ends():
    views = _views(25)
    held = held_out_indices(views, 10)
    assert sorted(views[i].name for i in held) == ["v05", "v15"] and held == sorted(held)


def test_too_few_views_hold_nothing_out():
    views = _views(19)
    assert held_out_indices(views, 10) == [] and held_out_indices(views, 1) == []


def test_a_plateau_stops_after_patience_checks_without_gain():
    p = Plateau(StopRule(interval=10, patience=2, min_delta=0.1))
    assert [p.observe(s, v) for s, v in [(10, 20.0), (20, 21.0), (30, 21.05), (40, 21.2), (50, 21.25), (60, 21.28)]] \
        == [False, False, False, False, False, True]
    assert p.stopped_at == 60 and p.best == 21.2


def test_the_floor_holds_a_stop_back_and_lower_is_better_for_a_loss():
    p = Plateau(StopRule(interval=1, patience=1, min_delta=0.0, floor=3, higher_is_better=False))
    assert [p.observe(s, v) for s, v in [(1, 1.0), (2, 1.5), (3, 0.9), (4, 0.95)]] == [False, False, False, True]
    assert p.best == 0.9


def test_a_non_finite_value_is_recorded_but_neither_a_gain_nor_a_loss_of_patience():
    p = Plateau(StopRule(interval=1, patience=2))
    assert not p.observe(1, math.nan) and p.best is None
    assert not p.observe(2, 5.0) and p.best == 5.0
    assert not p.observe(3, math.inf) and not p.observe(4, math.nan) and p.since_best == 0
    assert len(p.checks) == 4
    nan_only = Plateau(StopRule(interval=1, patience=1))
    assert not any(nan_only.observe(s, math.nan) for s in range(1, 10))  # a broken criterion never stops


def test_an_equal_value_is_no_gain_and_no_stop_at_the_cap():
    p = Plateau(StopRule(interval=1, patience=1, min_delta=0.0))
    assert not p.observe(1, 2.0) and not p.observe(2, 2.0, cap=2) and p.stopped_at is None and p.since_best == 1
    q = Plateau(StopRule(interval=1, patience=1, min_delta=0.0))
    assert not q.observe(1, 2.0) and q.observe(2, 2.0, cap=3) and q.stopped_at == 2


def test_whether_a_stop_can_come_before_the_cap():
    rule = StopRule(interval=10, patience=2)
    assert rule.can_stop_before(40, 10) and not rule.can_stop_before(30, 10)  # earliest stop 30
    assert not StopRule(interval=10, patience=1, floor=45).can_stop_before(50, 10)  # the floor: 50
    assert not StopRule().can_stop_before(10**6, 1)  # off


def test_state_round_trip_continues_the_same_decisions():
    a = Plateau(StopRule(interval=1, patience=2))
    for s, v in [(1, 1.0), (2, 0.5)]:
        a.observe(s, v)
    b = Plateau(StopRule(interval=1, patience=2))
    b.restore(a.state())
    assert a.observe(3, 0.7) == b.observe(3, 0.7) is True and b.checks == a.checks


def test_bad_rules_are_refused():
    with pytest.raises(ValueError, match="patience >= 1"):
        StopRule(interval=10, patience=0)


def test_summary_file_round_trip_and_corrupt_file(tmp_path):
    write_summary(tmp_path / "s.json", {"stopped_at": 5})
    assert read_summary(tmp_path / "s.json") == {"stopped_at": 5} and not (tmp_path / "s.json.tmp").exists()
    assert read_summary(tmp_path / "none.json") is None
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(ValueError, match="bad.json: not valid JSON"):
        read_summary(tmp_path / "bad.json")


def test_a_relative_gain_is_measured_against_the_first_checks_scale():
    # a loss that crosses zero: 2% of |the first value| (0.02) is the gain that counts
    p = Plateau(StopRule(interval=1, patience=1, min_delta=0.02, higher_is_better=False, relative=True))
    assert [p.observe(s, v) for s, v in [(1, 1.0), (2, 0.01), (3, -0.005), (4, -0.02)]] == [False, False, True, False]
