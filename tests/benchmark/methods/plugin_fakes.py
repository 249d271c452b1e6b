"""Fake plugins for the tests of entry-point loading: a module of a package, written into a
temporary folder, and ``importlib.metadata.entry_points`` answering entry points that name it."""

import dataclasses
import sys
import textwrap
from importlib import metadata

PLUGIN_MODULE = "fake_trase_bench_plugins"
GROUPS = ("trase_bench.methods", "trase_bench.objectives", "trase_bench.mask_generators")

# a package's module: a good method, methods broken in each way the registry checks, an
# objective and a mask generator, good and bad
SOURCE = textwrap.dedent('''
    import dataclasses

    from benchmark.methods import Method, MethodError
    from lazyspecs.presets import PresetTable


    @dataclasses.dataclass
    class Settings:
        preset: str = "paper"
        k: int = 3


    PRESETS = PresetTable("fake", Settings, error=MethodError)
    PRESETS.declare("paper", preset="paper")
    PRESETS.declare("cpu", base="paper", preset="cpu", k=2)
    ONLY_PAPER = PresetTable("fake-paper", Settings, error=MethodError)
    ONLY_PAPER.declare("paper", preset="paper")


    class Good(Method):
        """A fake method that does nothing useful."""

        presets = PRESETS

        def learn(self, *a, **k):
            raise NotImplementedError

        group = segment = learn


    class NoPresets(Good):
        presets = None


    class PaperOnly(Good):
        presets = ONLY_PAPER


    class Unfinished(Method):
        presets = PRESETS


    def not_a_class():
        return Good()


    class Generator:
        """Masks of nothing."""

        name = "nothing"
        needs_instance_map = False

        def generate(self, image, key="", instance_map=None):
            raise NotImplementedError

        def settings(self):
            return {}
''')


@dataclasses.dataclass
class FakeDist:
    name: str
    version: str


@dataclasses.dataclass
class FakeEntryPoint:
    name: str
    value: str
    group: str
    dist: FakeDist


def fake_plugins(monkeypatch, tmp_path):
    """A generator for a fixture: yields ``install({group: {name: value}}, package, version)``,
    which makes every registry read those entry points; they are forgotten afterwards."""
    from benchmark.methods import METHODS
    from masks.generators import GENERATORS
    from trase.objectives import OBJECTIVES

    (tmp_path / f"{PLUGIN_MODULE}.py").write_text(SOURCE)
    monkeypatch.syspath_prepend(str(tmp_path))
    registries = (METHODS, GENERATORS, OBJECTIVES)

    def install(points: dict[str, dict[str, str]], package: str = "fake-pkg", version: str = "1.2"):
        eps = [FakeEntryPoint(n, v, g, FakeDist(package, version)) for g, named in points.items()
               for n, v in named.items()]
        real = metadata.entry_points

        def entry_points(**select):  # the project's groups answered here, any other group (numba's) as installed
            if select.get("group") in GROUPS:
                return [e for e in eps if e.group == select["group"]]
            return real(**select)

        monkeypatch.setattr(metadata, "entry_points", entry_points)
        for reg in registries:
            reg.forget_plugins()

    yield install
    monkeypatch.undo()
    for reg in registries:
        reg.forget_plugins()
    sys.modules.pop(PLUGIN_MODULE, None)


def methods(**named) -> dict:
    """Entry points of the methods group: name (underscores as dashes) -> attribute of the module."""
    return {"trase_bench.methods": {k.replace("_", "-"): f"{PLUGIN_MODULE}:{v}" for k, v in named.items()}}
