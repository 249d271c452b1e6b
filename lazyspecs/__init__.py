"""The one registry mechanism of the project: names -> lazy ``"module:attr"`` specs.

Commands, perf suites, methods, feature objectives and mask generators are each a
``Registry``: an entry is declared with the import path of what it names, and the module is
imported only when the entry is used, so listing names never pays for torch, numba or
segment-anything (as nerfbaselines' method specs do). A package below the others (masks, trase,
baselines and benchmark all use it); written here because the libraries of the field offer
entry-point registries (importlib.metadata, catalogue), which need an installed distribution's
metadata to add an entry, where these tables are plain code.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Iterator
from typing import Any


@dataclasses.dataclass(frozen=True)
class Entry:
    name: str
    spec: str  # "package.module:attribute"
    help: str = ""  # one line, shown by listings

    def load(self) -> Any:
        module, _, attr = self.spec.partition(":")
        return getattr(importlib.import_module(module), attr)


class Registry:
    """Named entries of one kind; ``error`` is raised (one line) for an unknown name.

    A missing dependency inside an entry's module is not an unknown name: its
    ModuleNotFoundError propagates as it is."""

    def __init__(self, kind: str, error: type[Exception] = LookupError):
        self.kind = kind
        self.error = error
        self._entries: dict[str, Entry] = {}

    def add(self, name: str, spec: str, help: str = "") -> None:
        if ":" not in spec:
            raise ValueError(f"{self.kind} {name!r}: spec {spec!r} is not 'module:attribute'")
        old = self._entries.get(name)
        if old is not None and old.spec != spec:
            raise ValueError(f"{self.kind} {name!r} registered twice ({old.spec}, {spec})")
        self._entries[name] = Entry(name, spec, help)

    def register(self, name: str, help: str = "") -> Callable:
        """Class or function decorator: add it under ``name`` by its own import path."""

        def wrap(obj):
            self.add(name, f"{obj.__module__}:{obj.__qualname__}", help)
            return obj

        return wrap

    def entry(self, name: str) -> Entry:
        if name not in self._entries:
            known = ", ".join(self.names()) or "none"
            raise self.error(f"unknown {self.kind} {name!r}; known: {known}")
        return self._entries[name]

    def load(self, name: str) -> Any:
        """What ``name`` names, its module imported on first use."""
        return self.entry(name).load()

    def names(self) -> list[str]:
        return sorted(self._entries)

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[Entry]:
        return iter(self._entries[n] for n in self.names())

    def __len__(self) -> int:
        return len(self._entries)


__all__ = ["Entry", "Registry"]
