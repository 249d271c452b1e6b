"""Presets as data: named settings of one typed config, each value declared once, with the
conditions under which it applies written where it is declared (in the manner of
nerfbaselines' method presets and their ``@apply`` conditions).

A ``PresetTable`` belongs to whoever its config configures (the reconstruction declares its
presets in ``trase``, a method its own beside the method). A preset is an ordered list of
declarations, each a few field values and a condition on the ``Context`` (the benchmark, the
camera rig, the image size, the device); a preset may start from another (``base``). Resolving
a preset in a context applies the base's declarations, then its own, in order, where their
condition holds, over the config class's defaults, and keeps for every field where its value
was declared, so ``trase-bench presets`` can show it.

Written here (the package below all others) because the libraries of the field keep presets as
plain dicts merged by hand (nerfbaselines) or as code (gsplat's strategy defaults), and neither
records where a value came from.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import sys
import typing
from collections.abc import Callable, Iterator
from typing import Any


@dataclasses.dataclass(frozen=True)
class Context:
    """What a preset may depend on."""

    dataset: str | None = None  # a benchmark's key; None: a capture of one's own
    monocular: bool = True  # one moving camera; False: a multi-view rig
    image_size: tuple[int, int] | None = None  # (W, H) of the images a run evaluates at
    device: str = "cpu"  # where it trains: "cpu" or "cuda"
    objective: str | None = None  # the feature objective a run trains (a method's own, or --set's)


@dataclasses.dataclass(frozen=True)
class When:
    """A condition on the context, with the words ``trase-bench presets`` shows for it."""

    label: str
    test: Callable[[Context], bool]

    def __call__(self, ctx: Context) -> bool:
        return bool(self.test(ctx))

    def __and__(self, other: When) -> When:
        return When(f"{self.label} and {other.label}", lambda c: self(c) and other(c))


ALWAYS = When("always", lambda c: True)
MONOCULAR = When("monocular", lambda c: c.monocular)
MULTIVIEW = When("multi-view", lambda c: not c.monocular)
OWN_CAPTURE = When("a capture of one's own", lambda c: c.dataset is None)


def dataset(*keys: str) -> When:
    """The run is on one of these benchmarks."""
    return When(f"dataset {'/'.join(keys)}", lambda c: c.dataset in keys)


def objective(*names: str) -> When:
    """The run trains one of these feature objectives."""
    return When(f"objective {'/'.join(names)}", lambda c: c.objective in names)


def images_below(pixels: int) -> When:
    """The run's images hold fewer than ``pixels`` pixels each (W x H); false when the image
    size is not known (a preset listed without a scene)."""
    return When(f"images under {pixels:,} px", lambda c: c.image_size is not None
                and int(c.image_size[0]) * int(c.image_size[1]) < pixels)


@dataclasses.dataclass(frozen=True)
class Derived:
    """A value computed from the context (a training scale from the image size, say)."""

    fn: Callable[[Context], Any]
    label: str  # what it is, in words

    def __call__(self, ctx: Context) -> Any:
        return self.fn(ctx)


@dataclasses.dataclass(frozen=True)
class Declaration:
    values: dict[str, Any]  # dotted field -> value or Derived
    when: When
    source: str  # "path:line" of the declaring call


@dataclasses.dataclass
class Preset:
    name: str
    base: str | None  # the preset it starts from (in the same table)
    tier: str  # "paper" or "cpu": what a table without this name resolves instead
    help: str
    declarations: list[Declaration] = dataclasses.field(default_factory=list)


@dataclasses.dataclass(frozen=True)
class Resolved:
    """A preset resolved in a context: the typed config and where each field's value was declared."""

    name: str  # the preset asked for
    used: str  # the table's preset that answered it (the name itself, or its tier)
    config: Any
    sources: dict[str, str]  # dotted field -> "path:line (condition)[: derived value]" or "default (Class)"


class PresetError(LookupError):
    """An unknown preset, or a declaration naming a field its config does not have."""


class PresetTable:
    """The presets of one typed config class (a dataclass, possibly with dataclass fields).

    ``nested`` maps a field to the table of that field's own config: a preset of this table
    resolves that field in the nested table first (same name, same context), then applies its
    own declarations for ``field.sub`` on top."""

    def __init__(self, kind: str, config_cls: type, nested: dict[str, PresetTable] | None = None,
                 error: type[Exception] = PresetError):
        self.kind = kind
        self.config_cls = config_cls
        self.nested = dict(nested or {})
        self.error = error
        self._presets: dict[str, Preset] = {}

    # -- declaring ---------------------------------------------------------------------
    def declare(self, name: str, values: dict[str, Any] | None = None, *, base: str | None = None,
                tier: str | None = None, help: str = "", when: When = ALWAYS, **fields: Any) -> None:
        """Declare preset ``name`` (first call) or add to it: ``values`` (dotted names) and
        ``fields`` apply where ``when`` holds, after every earlier declaration of the preset."""
        values = {**(values or {}), **fields}
        for key in values:
            self._check_field(key, name)
        preset = self._presets.get(name)
        if preset is None:
            if base is not None and base not in self._presets:
                raise ValueError(f"{self.kind} preset {name!r}: base {base!r} is not declared (yet)")
            own_tier = tier or (self._presets[base].tier if base else name)
            preset = self._presets[name] = Preset(name, base, own_tier, help)
        elif base is not None and base != preset.base or tier is not None and tier != preset.tier:
            raise ValueError(f"{self.kind} preset {name!r}: base and tier are given where it is first declared")
        frame = sys._getframe(1)
        preset.declarations.append(Declaration(values, when, f"{frame.f_code.co_filename}:{frame.f_lineno}"))

    def _check_field(self, dotted: str, preset: str) -> None:
        cls = self.config_cls
        for part in dotted.split("."):
            if cls is dict:  # a free-form section (keyword arguments): any key
                return
            fields = {f.name: f for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else {}
            if part not in fields:
                raise ValueError(f"{self.kind} preset {preset!r}: {self.config_cls.__name__} has no field {dotted!r}")
            hint = hints(cls).get(part)
            cls = dict if hint is dict or typing.get_origin(hint) is dict else _dataclass_of(fields[part], cls)

    def extended(self, kind: str, config_cls: type | None = None) -> PresetTable:
        """A copy to which another owner adds declarations of its own (the benchmark's
        per-dataset schedules, a method built on another's settings), leaving this table as its
        owner declared it; ``config_cls`` a subclass with more fields."""
        out = PresetTable(kind, config_cls or self.config_cls, self.nested, self.error)
        out._presets = {n: dataclasses.replace(p, declarations=list(p.declarations)) for n, p in self._presets.items()}
        return out

    # -- reading -----------------------------------------------------------------------
    def names(self) -> list[str]:
        return list(self._presets)

    def __contains__(self, name: object) -> bool:
        return name in self._presets

    def __iter__(self) -> Iterator[Preset]:
        return iter(self._presets.values())

    def preset(self, name: str) -> Preset:
        if name not in self._presets:
            raise self.error(f"unknown {self.kind} preset {name!r}; known: {', '.join(self._presets)}")
        return self._presets[name]

    def chain(self, name: str) -> list[Preset]:
        """The preset and its bases, the root first."""
        out = [self.preset(name)]
        while out[-1].base is not None:
            out.append(self.preset(out[-1].base))
        return out[::-1]

    def resolve(self, name: str, ctx: Context, tier: str | None = None) -> Resolved:
        """Preset ``name`` in ``ctx``; a name this table does not declare resolves ``tier``
        (the run preset's tier, e.g. an earlier CPU geometry preset -> the method's ``cpu``)."""
        used = name if name in self._presets or tier is None else tier
        data, sources = _defaults(self.config_cls)
        for field, table in self.nested.items():
            # the nested table's preset: the nearest of this preset's chain that it declares
            own = next((p.name for p in reversed(self.chain(used)) if p.name in table), used)
            sub = table.resolve(own, ctx, tier)
            data[field] = dataclasses.asdict(sub.config)
            sources.update({f"{field}.{k}": v for k, v in sub.sources.items()})
        for preset in self.chain(used):
            for decl in preset.declarations:
                if not decl.when(ctx):
                    continue
                where = decl.source if decl.when is ALWAYS else f"{decl.source} ({decl.when.label})"
                for key, value in decl.values.items():
                    derived = isinstance(value, Derived)
                    _set(data, key, value(ctx) if derived else copy.deepcopy(value))
                    sources[key] = f"{where}: {value.label}" if derived else where
        return Resolved(name, used, build(self.config_cls, data), sources)


@functools.cache
def hints(cls: type) -> dict[str, Any]:
    """``typing.get_type_hints(cls)``, once per class (string annotations resolved as Python does)."""
    return typing.get_type_hints(cls)


def _dataclass_of(field: dataclasses.Field, owner: type) -> type | None:
    """The dataclass a field's annotation names."""
    hint = hints(owner).get(field.name)
    return hint if isinstance(hint, type) and dataclasses.is_dataclass(hint) else None


def _defaults(cls: type) -> tuple[dict, dict[str, str]]:
    """The class's default values and, for every (dotted) field, "default (<its class>)"."""
    data = dataclasses.asdict(cls())
    return data, _default_sources(cls)


def _default_sources(cls: type, prefix: str = "") -> dict[str, str]:
    out = {}
    for f in dataclasses.fields(cls):
        sub = _dataclass_of(f, cls)
        if sub is not None:
            out.update(_default_sources(sub, f"{prefix}{f.name}."))
        else:
            out[prefix + f.name] = f"default ({cls.__name__})"
    return out


def _set(data: dict, dotted: str, value: Any) -> None:
    *path, last = dotted.split(".")
    for part in path:
        data = data[part]
    data[last] = value


def build(cls: type, data: dict) -> Any:
    """``cls`` from a dict of its fields, nested dataclass fields built from their dicts."""
    kw = {}
    for f in dataclasses.fields(cls):
        if f.name not in data:
            continue
        sub = _dataclass_of(f, cls)
        kw[f.name] = build(sub, data[f.name]) if sub is not None and isinstance(data[f.name], dict) else data[f.name]
    return cls(**kw)


__all__ = ["ALWAYS", "MONOCULAR", "MULTIVIEW", "OWN_CAPTURE", "Context", "Declaration", "Derived", "Preset",
           "PresetError", "PresetTable", "Resolved", "When", "build", "dataset",
           "images_below"]
