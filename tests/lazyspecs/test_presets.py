"""Presets as data: declarations with conditions, bases, tiers, nested tables, and where each
value was declared."""

import dataclasses

import pytest

from lazyspecs.presets import (
    MONOCULAR,
    Context,
    Derived,
    PresetError,
    PresetTable,
    dataset,
    images_below,
    objective,
)


@dataclasses.dataclass
class Inner:
    steps: int = 10
    params: dict = dataclasses.field(default_factory=lambda: {"k": 1})


@dataclasses.dataclass
class Outer:
    inner: Inner = dataclasses.field(default_factory=Inner)
    lr: float = 0.1
    size: int = 0


def _tables():
    inner = PresetTable("inner", Inner)
    inner.declare("paper")
    inner.declare("cpu", base="paper", steps=3)
    outer = PresetTable("outer", Outer, nested={"inner": inner})
    outer.declare("paper", help="defaults")
    outer.declare("paper", when=dataset("a"), lr=0.5)
    outer.declare("cpu", base="paper", when=MONOCULAR, values={"inner.params.k": 7})
    outer.declare("cpu", size=Derived(lambda c: (c.image_size or (0, 0))[0] // 2, "half the width"))
    outer.declare("cpu-old", base="cpu", lr=0.2)
    return inner, outer


def test_declarations_apply_in_order_where_their_condition_holds_over_the_base():
    _, outer = _tables()
    r = outer.resolve("cpu", Context(dataset="a", monocular=True, image_size=(64, 48)))
    assert r.config == Outer(Inner(3, {"k": 7}), 0.5, 32) and r.used == "cpu"
    multi = outer.resolve("cpu", Context(dataset="b", monocular=False)).config
    assert multi == Outer(Inner(3, {"k": 1}), 0.1, 0)  # neither condition holds
    assert outer.resolve("cpu-old", Context()).config.lr == 0.2 and [p.name for p in outer.chain("cpu-old")] == [
        "paper", "cpu", "cpu-old"]


def test_images_below_reads_the_image_area_and_is_false_without_a_size():
    small = images_below(10_000)
    assert small(Context(image_size=(64, 48))) and not small(Context(image_size=(160, 120)))
    assert not small(Context(image_size=(100, 100))) and not small(Context())
    assert small.label == "images under 10,000 px"


def test_objective_reads_the_runs_objective_and_is_false_without_one():
    ours = objective("trase")
    assert ours(Context(objective="trase")) and not ours(Context(objective="cgc")) and not ours(Context())
    assert (ours & MONOCULAR).label == "objective trase and monocular"


def test_every_value_says_where_it_was_declared():
    _, outer = _tables()
    r = outer.resolve("cpu", Context(dataset="a"))
    assert r.sources["lr"].endswith("(dataset a)") and "test_presets.py:" in r.sources["lr"]
    assert r.sources["inner.params.k"].endswith("(monocular)")
    assert r.sources["inner.steps"].startswith(__file__)  # the nested table's declaration
    assert r.sources["size"].startswith(__file__) and not r.sources["size"].endswith(")")  # unconditional
    assert outer.resolve("paper", Context()).sources["inner.steps"] == "default (Inner)"


def test_a_name_the_table_does_not_declare_resolves_its_tier():
    inner, _ = _tables()
    assert inner.resolve("cpu-old", Context(), tier="cpu").used == "cpu"
    assert inner.preset("cpu").tier == "paper"  # a tier is inherited from the base unless given
    with pytest.raises(PresetError, match="unknown inner preset 'cpu-old'; known: paper, cpu"):
        inner.resolve("cpu-old", Context())


def test_bad_declarations_fail_where_they_are_made():
    _, outer = _tables()
    with pytest.raises(ValueError, match="Outer has no field 'inner.nope'"):
        outer.declare("paper", values={"inner.nope": 1})
    with pytest.raises(ValueError, match="base 'gpu' is not declared"):
        outer.declare("x", base="gpu")
    with pytest.raises(ValueError, match="base and tier are given where it is first declared"):
        outer.declare("cpu", base="cpu-old")


def test_an_extended_table_leaves_its_owners_table_alone():
    _, outer = _tables()
    more = outer.extended("more")
    more.declare("paper", lr=0.9)
    assert more.resolve("paper", Context()).config.lr == 0.9
    assert outer.resolve("paper", Context()).config.lr == 0.1
