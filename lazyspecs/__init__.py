"""The one registry mechanism of the project: names -> lazy ``"module:attr"`` specs.

Commands, perf suites, methods, feature objectives and mask generators are each a
``Registry``: an entry is declared with the import path of what it names, and the module is
imported only when the entry is used, so listing names never pays for torch, numba or
segment-anything (as nerfbaselines' method specs do). A package below the others (masks, trase,
baselines and benchmark all use it); written here because the libraries of the field offer
entry-point registries (importlib.metadata, catalogue), which need an installed distribution's
metadata to add an entry, where the project's own tables are plain code.

The project's own entries are plain code (``add``). A registry given an entry-point ``group``
also holds the entries that installed packages declare there (Python entry points, read with
importlib.metadata the first time a name is not one of its own): a plugin's entry is an
``Entry`` like the others, with an ``Origin`` (its package, version and entry point). Plugins
never break the project's names: a plugin named like an entry of the project is ignored, two
plugins of one name are both refused, and a plugin that fails to import or is not what the
registry holds (``check``) is an error of the registry's kind, one line naming its package and
entry point, when it is used; ``problems`` lists what is wrong without importing anything.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Iterator
from importlib import metadata
from typing import Any


@dataclasses.dataclass(frozen=True)
class Origin:
    """Where a plugin entry was declared: an entry point of an installed distribution."""

    package: str  # the distribution's name
    version: str
    group: str  # the entry-point group
    entry_point: str  # "name = module:attribute", as the package declared it

    def __str__(self) -> str:
        return f"entry point '{self.entry_point}' of package {self.package} {self.version}"


@dataclasses.dataclass(frozen=True)
class Entry:
    name: str
    spec: str  # "package.module:attribute" ("package.module" alone: the module itself)
    help: str = ""  # one line, shown by listings
    origin: Origin | None = None  # None: declared by this project

    @property
    def source(self) -> str:
        """The word built-in, or the plugin's package and version."""
        return "built-in" if self.origin is None else f"{self.origin.package} {self.origin.version}"

    def load(self) -> Any:
        module, _, attr = self.spec.partition(":")
        obj = importlib.import_module(module.strip())
        for part in attr.strip().split(".") if attr.strip() else ():
            obj = getattr(obj, part)
        return obj


class Registry:
    """Named entries of one kind; ``error`` is raised (one line) for an unknown name.

    A missing dependency inside a built-in entry's module is not an unknown name: its
    ModuleNotFoundError propagates as it is. ``group``: the entry-point group from which
    installed packages add entries; ``check(obj)``: what is wrong with a plugin's object for
    this registry (a phrase), or None."""

    def __init__(self, kind: str, error: type[Exception] = LookupError, group: str | None = None,
                 check: Callable[[Any], str | None] | None = None):
        self.kind = kind
        self.error = error
        self.group = group
        self.check = check
        self._entries: dict[str, Entry] = {}
        self._plugins: dict[str, list[Entry]] | None = None  # name -> entries; None: not read yet
        self._read_error: str | None = None

    def add(self, name: str, spec: str, help: str = "") -> None:
        if ":" not in spec:
            raise ValueError(f"{self.kind} {name!r}: spec {spec!r} is not 'module:attribute'")
        plugin = self._plugin(name)
        if plugin is not None and plugin.spec == spec:  # a plugin's module naming itself: keep its origin
            return
        old = self._entries.get(name)
        if old is not None and old.spec != spec:
            raise ValueError(f"{self.kind} {name!r} registered twice ({old.spec}, {spec})")
        if old is not None and not help:  # a module's decorator naming a declared entry keeps its line
            return
        self._entries[name] = Entry(name, spec, help)

    def register(self, name: str, help: str = "") -> Callable:
        """Class or function decorator: add it under ``name`` by its own import path."""

        def wrap(obj):
            self.add(name, f"{obj.__module__}:{obj.__qualname__}", help)
            return obj

        return wrap

    def entry(self, name: str) -> Entry:
        if name in self._entries:
            return self._entries[name]
        found = self.plugins().get(name, [])
        if len(found) > 1:
            raise self.error(_conflict(self.kind, name, found))
        if not found:
            known = ", ".join(self.names()) or "none"
            raise self.error(f"unknown {self.kind} {name!r}; known: {known}")
        return found[0]

    def load(self, name: str) -> Any:
        """What ``name`` names, its module imported on first use. A plugin that cannot be
        imported, or whose object fails ``check``, is a one-line ``error`` naming its package
        and entry point."""
        entry = self.entry(name)
        if entry.origin is None:
            return entry.load()
        try:
            obj = entry.load()
        except Exception as exc:  # any failure of another package's module: one line
            raise self.error(f"{self.kind} {name!r} ({entry.origin}): cannot be loaded: {_one_line(exc)}") from exc
        problem = self.check(obj) if self.check is not None else None
        if problem:
            raise self.error(f"{self.kind} {name!r} ({entry.origin}): {problem}")
        return obj

    # -- plugins ---------------------------------------------------------------------------
    def plugins(self) -> dict[str, list[Entry]]:
        """The entries installed packages declare in ``group``, by name (read once); a name
        the project itself registers is not among them (``problems`` says so)."""
        if self._plugins is None:
            self._plugins = {} if self.group is None else self._read_plugins()
        return {n: es for n, es in self._plugins.items() if n not in self._entries}

    def _plugin(self, name: str) -> Entry | None:
        found = (self._plugins or {}).get(name, [])
        return found[0] if len(found) == 1 else None

    def _read_plugins(self) -> dict[str, list[Entry]]:
        try:
            points = list(metadata.entry_points(group=self.group))
        except Exception as exc:  # noqa: BLE001 - a distribution with unreadable metadata
            self._read_error = f"entry points of group {self.group} unreadable: {_one_line(exc)}"
            return {}
        out: dict[str, list[Entry]] = {}
        for ep in points:
            dist = getattr(ep, "dist", None)
            package = _dist_name(dist)
            version = getattr(dist, "version", None) or "(version unknown)"
            origin = Origin(package, version, self.group, f"{ep.name} = {ep.value}")
            entry = Entry(ep.name, ep.value, "", origin)
            same = [e for e in out.get(ep.name, []) if e.origin.package == package and e.spec == entry.spec]
            if not same:  # one distribution seen twice on the path counts once
                out.setdefault(ep.name, []).append(entry)
        for name, found in out.items():
            own = self._entries.get(name)
            if own is not None and len(found) == 1 and own.spec == found[0].spec:
                self._entries[name] = found[0]  # registered in code by the plugin's own module: the plugin
        return out

    def problems(self) -> list[str]:
        """One line per plugin that cannot be used by its name, without importing any: named
        like an entry of the project (ignored), or declared by two packages (both refused)."""
        self.plugins()
        out = [self._read_error] if self._read_error else []
        for name, found in sorted((self._plugins or {}).items()):
            if name in self._entries and self._entries[name].origin is None:
                out += [f"{self.kind} {name!r} ({e.origin}) is ignored: a built-in {self.kind} has that name"
                        for e in found]
            elif len(found) > 1:
                out.append(_conflict(self.kind, name, found))
        return out

    def forget_plugins(self) -> None:
        """Read the entry points again on next use (after installing a package in-process)."""
        self._plugins, self._read_error = None, None
        self._entries = {n: e for n, e in self._entries.items() if e.origin is None}

    # -- listing ---------------------------------------------------------------------------
    def names(self) -> list[str]:
        """The project's names and every usable plugin's (one package per name)."""
        return sorted({*self._entries, *(n for n, es in self.plugins().items() if len(es) == 1)})

    def __contains__(self, name: object) -> bool:
        if name in self._entries:
            return True
        return len(self.plugins().get(name, [])) == 1 if isinstance(name, str) else False

    def __iter__(self) -> Iterator[Entry]:
        return iter(self.entry(n) for n in self.names())

    def __len__(self) -> int:
        return len(self.names())


def subclass_of(spec: str) -> Callable[[Any], str | None]:
    """A ``check``: the object must be a subclass of the class at ``spec`` ("module:Class"),
    imported when a plugin is checked."""

    def check(obj: Any) -> str | None:
        base = Entry("base", spec).load()
        if isinstance(obj, type) and issubclass(obj, base):
            return None
        return f"{describe(obj)} is not a subclass of {base.__module__}.{base.__qualname__}"

    return check


def describe(obj: Any) -> str:
    """An object in a few words, for an error: "class pkg.mod.Name", "function f", "a str"."""
    if isinstance(obj, type):
        return f"class {obj.__module__}.{obj.__qualname__}"
    if callable(obj) and hasattr(obj, "__qualname__"):
        return f"{type(obj).__name__} {getattr(obj, '__module__', '?')}.{obj.__qualname__}"
    return f"a {type(obj).__name__}"


def _conflict(kind: str, name: str, found: list[Entry]) -> str:
    who = "; ".join(str(e.origin) for e in found)
    return f"{kind} {name!r} is declared by {len(found)} packages ({who}): uninstall all but one"


def _dist_name(dist) -> str:
    if dist is None:
        return "(unknown package)"
    name = getattr(dist, "name", None)  # Python >= 3.10
    if not name:
        try:
            name = dist.metadata["Name"]
        except Exception:  # noqa: BLE001 - unreadable metadata: the package stays unnamed
            name = None
    return name or "(unknown package)"


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


__all__ = ["Entry", "Origin", "Registry", "describe", "subclass_of"]
