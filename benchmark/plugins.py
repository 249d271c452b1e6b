"""Methods, objectives and mask generators from other packages (docs/methods.md).

An installed package adds entries to three registries by declaring Python entry points, one
group per kind; each registry reads its group the first time a name is not one of its own
(lazyspecs.Registry), so a plugin costs nothing until it is named:

    group                         registry                      an entry point names
    trase_bench.methods           benchmark.methods.METHODS     a Method subclass that declares presets
    trase_bench.objectives        trase.objectives.OBJECTIVES   an Objective subclass
    trase_bench.mask_generators   masks.generators.GENERATORS   a mask generator class (generate, settings)

A run records the package and version of every plugin it used (results.json ``versions``),
and the stage cache keys their stages by them, so a new release of a plugin computes again.
"""

from __future__ import annotations

import dataclasses
import importlib

# kind (as listings name it) -> (entry-point group, "module:REGISTRY", how a run names one)
KINDS = {
    "method": ("trase_bench.methods", "benchmark.methods:METHODS", "trase-bench run --method NAME"),
    "objective": ("trase_bench.objectives", "trase.objectives:OBJECTIVES", "--set method.features.objective=NAME"),
    "mask generator": ("trase_bench.mask_generators", "masks.generators:GENERATORS", "--set masks.generator=NAME"),
}


def registry(kind: str):
    """The registry of ``kind`` (its module imported: the objectives' imports torch)."""
    module, _, attr = KINDS[kind][1].partition(":")
    return getattr(importlib.import_module(module), attr)


def packages(*named: tuple[object, str | None]) -> dict[str, str]:
    """{package: version} of the plugins among (registry, name) pairs; built-in and unknown
    names give nothing."""
    out = {}
    for reg, name in named:
        if isinstance(name, str) and name in reg:
            origin = reg.entry(name).origin
            if origin is not None:
                out[origin.package] = origin.version
    return out


def _objective(settings) -> str | None:
    return getattr(getattr(settings.method, "features", None), "objective", None)


def feature_packages(method, settings) -> dict[str, str]:
    """Plugins that make a run's features: its method and the objective its settings name."""
    from benchmark.methods import METHODS

    named = [(METHODS, method.name)]
    if isinstance(_objective(settings), str):
        from trase.objectives import OBJECTIVES

        named.append((OBJECTIVES, _objective(settings)))
    return packages(*named)


def mask_packages(settings) -> dict[str, str]:
    """The plugin a run's masks come from, if its generator is one."""
    from masks.generators import GENERATORS

    return packages((GENERATORS, getattr(settings.masks, "generator", None)))


def run_packages(method, settings) -> dict[str, str]:
    """Every plugin a run used: its method, objective and mask generator."""
    return {**mask_packages(settings), **feature_packages(method, settings)}


@dataclasses.dataclass(frozen=True)
class Listed:
    """One entry of a listing: name, where it comes from, one line about it; ``error`` for a
    plugin that cannot be used."""

    name: str
    source: str  # "built-in" or "<package> <version>"
    description: str
    package: str | None = None
    version: str | None = None
    entry_point: str | None = None
    error: str | None = None

    def to_dict(self) -> dict:
        return {k: v for k, v in dataclasses.asdict(self).items() if k != "name"}


def listing(kind: str) -> tuple[list[Listed], list[str]]:
    """Every entry of ``kind`` and the one-line warnings of its plugins. Built-in entries are
    described by their registry line, unimported; each plugin is imported and checked (its
    description: the first line of its docstring), and one that fails is a warning."""
    if kind == "objective":
        import baselines  # noqa: F401 (registers the baselines' objectives, as a run's methods do)
    reg = registry(kind)
    rows, warnings = [], list(reg.problems())
    for entry in reg:
        if entry.origin is None:
            rows.append(Listed(entry.name, entry.source, entry.help or _doc_line(reg.load(entry.name))))
            continue
        o = entry.origin
        try:
            obj = reg.load(entry.name)
        except reg.error as exc:  # the registry's one-line error
            warnings.append(str(exc))
            rows.append(Listed(entry.name, entry.source, "", o.package, o.version, o.entry_point, str(exc)))
            continue
        rows.append(Listed(entry.name, entry.source, _doc_line(obj), o.package, o.version, o.entry_point))
    return rows, warnings


def _doc_line(obj) -> str:
    doc = (getattr(obj, "__doc__", None) or "").strip()
    return doc.splitlines()[0].strip() if doc else "(no description: the class has no docstring)"


__all__ = ["KINDS", "Listed", "feature_packages", "listing", "mask_packages", "packages", "registry",
           "run_packages"]
