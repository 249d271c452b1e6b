"""Entries from installed packages (entry points): read lazily, listed with their origin, and a
broken one is a one-line error naming its package and entry point, never a crash elsewhere."""

import dataclasses
import sys
from importlib import metadata

import pytest

from lazyspecs import Registry, subclass_of

GROUP = "lazyspecs_tests.things"


class Unknown(LookupError):
    pass


@dataclasses.dataclass
class FakeDist:
    name: str
    version: str


@dataclasses.dataclass
class FakeEntryPoint:
    name: str
    value: str
    group: str
    dist: FakeDist | None


def install(monkeypatch, *points, calls=None):
    """``metadata.entry_points`` answering ``points`` (package, name, value) for GROUP."""
    eps = [FakeEntryPoint(n, v, GROUP, FakeDist(p, "1.2") if p else None) for p, n, v in points]

    real = metadata.entry_points

    def entry_points(**select):
        if select.get("group") != GROUP:  # other groups (numba's) as installed
            return real(**select)
        if calls is not None:
            calls.append(GROUP)
        return [e for e in eps if e.group == GROUP]

    monkeypatch.setattr(metadata, "entry_points", entry_points)


def things(**kw):
    reg = Registry("thing", Unknown, group=GROUP, **kw)
    reg.add("own", "json:dumps", "the project's own")
    return reg


def test_plugins_are_read_once_and_only_when_a_name_is_not_the_projects(monkeypatch):
    calls = []
    install(monkeypatch, ("pkg-a", "plug", "json:loads"), calls=calls)
    reg = things()
    assert reg.load("own") is __import__("json").dumps and calls == []  # a built-in name reads nothing
    assert reg.load("plug") is __import__("json").loads and calls == [GROUP]
    assert reg.names() == ["own", "plug"] and "plug" in reg and len(reg) == 2
    assert calls == [GROUP]  # read once
    e = reg.entry("plug")
    assert e.source == "pkg-a 1.2" and reg.entry("own").source == "built-in"
    assert str(e.origin) == "entry point 'plug = json:loads' of package pkg-a 1.2"
    assert [x.name for x in reg] == ["own", "plug"]


def test_a_registry_without_group_reads_no_entry_points(monkeypatch):
    calls = []
    install(monkeypatch, ("pkg-a", "plug", "json:loads"), calls=calls)
    reg = Registry("thing", Unknown)
    with pytest.raises(Unknown, match="unknown thing 'plug'; known: none"):
        reg.entry("plug")
    assert calls == [] and reg.problems() == []


def test_a_plugin_that_cannot_be_imported_is_one_line_naming_package_and_entry_point(monkeypatch):
    install(monkeypatch, ("pkg-b", "gone", "no_such_module_for_tests:Thing"))
    reg = things()
    assert "gone" in reg.names()  # listed without importing it
    with pytest.raises(Unknown) as err:
        reg.load("gone")
    msg = str(err.value)
    assert "\n" not in msg
    assert msg == ("thing 'gone' (entry point 'gone = no_such_module_for_tests:Thing' of package pkg-b 1.2): "
                   "cannot be loaded: ModuleNotFoundError: No module named 'no_such_module_for_tests'")
    assert reg.load("own")  # the others still work


def test_a_plugin_whose_module_raises_is_one_line(monkeypatch, tmp_path):
    (tmp_path / "plugin_that_raises.py").write_text("raise RuntimeError('first line\\nsecond line')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    install(monkeypatch, ("pkg-c", "boom", "plugin_that_raises:Thing"))
    with pytest.raises(Unknown, match=r"^thing 'boom' \(entry point 'boom = plugin_that_raises:Thing' of package "
                                      r"pkg-c 1.2\): cannot be loaded: RuntimeError: first line$"):
        things().load("boom")
    sys.modules.pop("plugin_that_raises", None)


def test_a_plugin_of_the_wrong_type_is_refused_by_check(monkeypatch):
    install(monkeypatch, ("pkg-d", "wrong", "json:dumps"), ("pkg-d", "right", "json:JSONDecoder"))
    reg = things(check=subclass_of("json:JSONDecoder"))
    assert reg.load("right") is __import__("json").JSONDecoder
    with pytest.raises(Unknown, match=r"^thing 'wrong' \(entry point 'wrong = json:dumps' of package pkg-d 1.2\): "
                                      r"function json.dumps is not a subclass of json.decoder.JSONDecoder$"):
        reg.load("wrong")


def test_a_plugin_named_like_a_builtin_is_ignored_with_a_warning(monkeypatch):
    install(monkeypatch, ("pkg-e", "own", "json:loads"))
    reg = things()
    assert reg.load("own") is __import__("json").dumps  # the project's entry wins
    assert reg.names() == ["own"]
    assert reg.problems() == [("thing 'own' (entry point 'own = json:loads' of package pkg-e 1.2) is ignored: "
                               "a built-in thing has that name")]


def test_two_packages_declaring_one_name_are_both_refused(monkeypatch):
    install(monkeypatch, ("pkg-f", "twin", "json:loads"), ("pkg-g", "twin", "json:dumps"),
            ("pkg-f", "solo", "json:loads"))
    reg = things()
    assert reg.names() == ["own", "solo"] and "twin" not in reg
    expected = ("thing 'twin' is declared by 2 packages (entry point 'twin = json:loads' of package pkg-f 1.2; "
                "entry point 'twin = json:dumps' of package pkg-g 1.2): uninstall all but one")
    with pytest.raises(Unknown) as err:
        reg.load("twin")
    assert str(err.value) == expected and reg.problems() == [expected]


def test_one_distribution_seen_twice_counts_once(monkeypatch):
    install(monkeypatch, ("pkg-h", "dup", "json:loads"), ("pkg-h", "dup", "json:loads"))
    reg = things()
    assert reg.load("dup") is __import__("json").loads and reg.problems() == []


def test_an_entry_point_without_distribution_still_names_itself(monkeypatch):
    install(monkeypatch, (None, "orphan", "no_such_module_for_tests:X"))
    with pytest.raises(Unknown, match=r"entry point 'orphan = no_such_module_for_tests:X' of package "
                                      r"\(unknown package\) \(version unknown\)"):
        things().load("orphan")


def test_unreadable_entry_points_are_a_problem_not_a_crash(monkeypatch):
    real = metadata.entry_points

    def broken(**select):
        if select.get("group") != GROUP:
            return real(**select)
        raise OSError("metadata of some package unreadable")

    monkeypatch.setattr(metadata, "entry_points", broken)
    reg = things()
    assert reg.names() == ["own"]
    assert reg.problems() == [(f"entry points of group {GROUP} unreadable: OSError: metadata of some package "
                               "unreadable")]


def test_a_plugin_module_registering_itself_keeps_its_origin(monkeypatch, tmp_path):
    # a plugin's module that also uses the registry's decorator (as built-in modules do)
    (tmp_path / "plugin_self_registering.py").write_text(
        "import lazyspecs_registry_under_test as R\n"
        "@R.REG.register('selfish')\n"
        "class Thing:\n    pass\n")
    reg = things()
    monkeypatch.setitem(sys.modules, "lazyspecs_registry_under_test", type(sys)("lazyspecs_registry_under_test"))
    sys.modules["lazyspecs_registry_under_test"].REG = reg
    monkeypatch.syspath_prepend(str(tmp_path))
    install(monkeypatch, ("pkg-i", "selfish", "plugin_self_registering:Thing"))
    obj = reg.load("selfish")
    assert obj.__name__ == "Thing" and reg.entry("selfish").source == "pkg-i 1.2" and reg.problems() == []
    sys.modules.pop("plugin_self_registering", None)


def test_forget_plugins_reads_again(monkeypatch):
    install(monkeypatch, ("pkg-j", "first", "json:loads"))
    reg = things()
    assert reg.names() == ["first", "own"]
    install(monkeypatch, ("pkg-j", "second", "json:loads"))
    assert reg.names() == ["first", "own"]  # read once
    reg.forget_plugins()
    assert reg.names() == ["own", "second"]


def test_entry_points_may_name_a_module_or_a_nested_attribute(monkeypatch):
    install(monkeypatch, ("pkg-k", "module", "json"), ("pkg-k", "nested", "json:JSONDecoder.decode"))
    reg = things()
    assert reg.load("module") is __import__("json")
    assert reg.load("nested") is __import__("json").JSONDecoder.decode
