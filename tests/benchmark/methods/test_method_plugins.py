"""Methods, objectives and mask generators from installed packages (entry points), with fake
entry points: loaded by name like the built-in ones, named by the name they were asked by, and
a broken one is a one-line error naming its package and entry point when it is used."""

import dataclasses

import pytest

from benchmark.cli import main
from benchmark.methods import METHODS, MethodError, get_method
from benchmark.methods.trase_method import TraseMethod
from benchmark.plugins import feature_packages, packages, run_packages
from masks.generators import GENERATORS, make_generator
from masks.maskset import MaskError
from tests.benchmark.methods.plugin_fakes import PLUGIN_MODULE, fake_plugins, methods


@pytest.fixture
def plugins(monkeypatch, tmp_path):
    yield from fake_plugins(monkeypatch, tmp_path)


def test_a_plugin_method_is_built_by_name_and_resolves_its_presets(plugins):
    plugins(methods(good="Good"))
    assert "good" in METHODS.names() and "trase" in METHODS.names()
    m = get_method("good")
    assert type(m).__name__ == "Good" and m.name == "good"  # the name it was asked by keys its runs
    assert m.settings("paper", "hypernerf").k == 3 and m.settings("cpu", "hypernerf").k == 2
    assert m.settings("cpu-v2", "hypernerf").k == 2  # an earlier cpu preset resolves the cpu tier
    assert METHODS.entry("good").source == "fake-pkg 1.2"


def test_a_builtin_is_still_named_as_registered():
    m = get_method("trase-hard")
    assert isinstance(m, TraseMethod) and m.name == "trase-hard"


@pytest.mark.parametrize("value, problem", [
    ("not_a_class", "function fake_trase_bench_plugins.not_a_class is not a subclass of benchmark.methods.Method"),
    ("NoPresets", ("class NoPresets declares no presets (Method.presets: a lazyspecs.presets.PresetTable of its "
                   "settings class)")),
    ("PaperOnly", "class PaperOnly declares no 'cpu' preset (every run resolves one of paper, cpu)"),
    ("Unfinished", "class Unfinished does not implement learn, group, segment"),
    ("Missing", "cannot be loaded: AttributeError: module 'fake_trase_bench_plugins' has no attribute 'Missing'"),
])
def test_a_broken_method_plugin_is_one_line_naming_package_and_entry_point(plugins, value, problem):
    plugins(methods(broken=value))
    with pytest.raises(MethodError) as err:
        get_method("broken")
    assert str(err.value) == (f"method 'broken' (entry point 'broken = {PLUGIN_MODULE}:{value}' of package "
                              f"fake-pkg 1.2): {problem}")
    assert get_method("trase").name == "trase"  # every other method still works


def test_a_plugin_that_cannot_be_imported_fails_only_where_it_is_used(plugins, capsys):
    plugins({"trase_bench.methods": {"gone": "no_such_package_for_tests.method:Gone"}})
    assert main(["presets", "--method", "gone", "--dataset", "hypernerf"]) == 1
    err = capsys.readouterr().err
    assert err == ("error: method 'gone' (entry point 'gone = no_such_package_for_tests.method:Gone' of package "
                   "fake-pkg 1.2): cannot be loaded: ModuleNotFoundError: No module named "
                   "'no_such_package_for_tests'\n")
    assert main(["presets", "--method", "trase", "--dataset", "hypernerf", "--preset", "cpu"]) == 0


def test_a_plugin_named_like_a_builtin_method_is_ignored(plugins):
    plugins(methods(trase="Good"))
    assert isinstance(get_method("trase"), TraseMethod)
    assert METHODS.problems() == [(f"method 'trase' (entry point 'trase = {PLUGIN_MODULE}:Good' of package fake-pkg "
                                   "1.2) is ignored: a built-in method has that name")]


def test_an_unknown_method_lists_the_plugins_too(plugins):
    plugins(methods(good="Good"))
    with pytest.raises(MethodError, match=r"unknown method 'nope'; known: cgc, good, opengaussian, trase"):
        get_method("nope")


def test_objective_plugins_load_by_name_and_are_checked(plugins):
    from trase.objectives import OBJECTIVES, ObjectiveInputError, get_objective
    from trase.objectives.soft import SoftMining

    plugins({"trase_bench.objectives": {"soft-again": "trase.objectives.soft:SoftMining",
                                        "not-one": f"{PLUGIN_MODULE}:Good"}})
    objective = get_objective("soft-again")
    assert isinstance(objective, SoftMining) and objective.name == "soft-again"
    assert OBJECTIVES.entry("soft-again").source == "fake-pkg 1.2"
    with pytest.raises(ObjectiveInputError, match=r"^objective 'not-one' \(entry point 'not-one = "
                       r"fake_trase_bench_plugins:Good' of package fake-pkg 1.2\): class fake_trase_bench_plugins.Good "
                       r"is not a subclass of trase.objectives.base.Objective$"):
        get_objective("not-one")


def test_mask_generator_plugins_load_by_name_and_are_checked(plugins):
    plugins({"trase_bench.mask_generators": {"nothing": f"{PLUGIN_MODULE}:Generator",
                                             "not-one": f"{PLUGIN_MODULE}:not_a_class"}})
    assert make_generator("nothing").name == "nothing"
    assert "nothing" in GENERATORS.names() and "classical" in GENERATORS.names()
    with pytest.raises(MaskError, match=r"^mask generator 'not-one' \(entry point 'not-one = "
                       r"fake_trase_bench_plugins:not_a_class' of package fake-pkg 1.2\): function "
                       r"fake_trase_bench_plugins.not_a_class is not a mask generator class"):
        make_generator("not-one")


def test_a_run_records_the_packages_of_its_plugins(plugins):
    plugins({**methods(good="Good"), "trase_bench.mask_generators": {"nothing": f"{PLUGIN_MODULE}:Generator"},
             "trase_bench.objectives": {"soft-again": "trase.objectives.soft:SoftMining"}},
            package="fake-pkg", version="3.1")

    @dataclasses.dataclass
    class Masks:
        generator: str

    @dataclasses.dataclass
    class Run:
        masks: Masks
        method: object

    good, trase = get_method("good"), get_method("trase")
    cpu = trase.settings("cpu", "hypernerf")
    assert run_packages(good, Run(Masks("nothing"), good.settings("cpu", "hypernerf"))) == {"fake-pkg": "3.1"}
    assert run_packages(trase, Run(Masks("synthetic"), cpu)) == {}  # built-ins add nothing to keys or records
    cpu.features.objective = "not-registered"  # unknown names are the run's own error, not a package
    assert run_packages(trase, Run(Masks("synthetic"), cpu)) == {}
    cpu.features.objective = "soft-again"  # a built-in method with an objective from a package
    assert feature_packages(trase, Run(Masks("synthetic"), cpu)) == {"fake-pkg": "3.1"}
    assert packages((METHODS, "trase"), (METHODS, "nope"), (METHODS, None)) == {}
