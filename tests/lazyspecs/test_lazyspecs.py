"""The one registry mechanism: lazy "module:attr" specs, clear errors, no silent misses."""

import sys

import pytest

from lazyspecs import Registry


class Unknown(LookupError):
    pass


def test_entries_load_on_first_use_and_list_sorted():
    sys.modules.pop("colorsys", None)
    reg = Registry("thing", Unknown)
    reg.add("b", "json:dumps", "second")
    reg.add("a", "colorsys:rgb_to_hsv", "first")
    assert reg.names() == ["a", "b"] and [e.help for e in reg] == ["first", "second"] and len(reg) == 2
    assert "a" in reg and "colorsys" not in sys.modules  # adding and listing imported nothing
    assert reg.load("a")(1, 0, 0)[2] == 1 and "colorsys" in sys.modules


def test_unknown_names_and_bad_specs_are_one_line_errors():
    reg = Registry("thing", Unknown)
    reg.add("a", "json:dumps")
    with pytest.raises(Unknown, match=r"unknown thing 'z'; known: a"):
        reg.load("z")
    with pytest.raises(ValueError, match="is not 'module:attribute'"):
        reg.add("c", "json.dumps")
    reg.add("a", "json:dumps")  # the same entry again is harmless
    with pytest.raises(ValueError, match="registered twice"):
        reg.add("a", "json:loads")


def test_a_missing_dependency_is_not_an_unknown_name():
    reg = Registry("thing", Unknown)
    reg.add("gone", "no_such_module_here:thing")
    with pytest.raises(ModuleNotFoundError):
        reg.load("gone")


def test_decorator_registers_by_import_path():
    reg = Registry("thing")

    @reg.register("mine", "help line")
    class Mine:
        pass

    assert reg.entry("mine").spec == f"{__name__}:test_decorator_registers_by_import_path.<locals>.Mine"


def test_project_registries_resolve():
    from benchmark.cli import COMMANDS
    from benchmark.methods import METHODS, get_method
    from benchmark.perf import SUITES
    from masks.generators import GENERATORS
    from trase.objectives import get_objective

    for reg in (COMMANDS, SUITES, METHODS, GENERATORS):
        for e in reg:
            assert callable(e.load()), e
    assert get_method("cgc").name == "cgc"
    assert get_objective("cgc").name == "cgc"  # the benchmark's methods brought the baselines in


def test_a_decorator_naming_a_declared_entry_keeps_its_help_line():
    reg = Registry("thing")
    reg.add("mine", "json:dumps", "declared with a line")
    reg.register("mine")(__import__("json").dumps)  # the module's own decorator, as it is imported
    assert reg.entry("mine").help == "declared with a line"
