"""Run configuration: nested sections, per-dataset defaults, ``--set key=value`` overrides.

Sections: ``masks`` (2D mask generation), ``geometry`` (reconstruction or ground-truth
geometry), ``method`` (the method's own settings: features, clustering, filtering), and
``prompts``. Each stage's cache key hashes only its own section plus its inputs' keys, so
changing a clustering setting reuses the masks and the reconstruction.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import types
import typing

from benchmark.errors import UserError
from lazyspecs.presets import hints as type_hints


class ConfigError(UserError):
    """A bad --set override or config value."""


def parse_overrides(items: list[str] | tuple[str, ...]) -> dict:
    """``["method.features.dim=16", "geometry.source=ground-truth"]`` -> nested dict.

    Values are parsed as JSON when they can be (numbers, true/false, null, lists), else kept
    as strings.
    """
    out: dict = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected key=value")
        key, raw = item.split("=", 1)
        parts = [p for p in key.strip().split(".") if p]
        if not parts:
            raise ConfigError(f"--set {item!r}: empty key")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        node = out
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"--set {item!r}: {p!r} is both a value and a section")
        node[parts[-1]] = value
    return out


def merge(base: dict, overrides: dict, path: str = "") -> dict:
    """Deep-merge ``overrides`` into a copy of ``base``; unknown keys are errors (typos),
    except inside sections named ``*params`` (keyword arguments passed through as given)."""
    out = copy.deepcopy(base)
    open_section = path.rstrip(".").endswith("params")  # free-form keyword arguments
    for k, v in overrides.items():
        where = f"{path}{k}"
        if k not in out and open_section:
            out[k] = v
            continue
        if k not in out:
            known = ", ".join(sorted(out)) or "none"
            raise ConfigError(f"--set {where}: unknown setting (known here: {known})")
        if isinstance(out[k], dict):
            if not isinstance(v, dict):
                raise ConfigError(f"--set {where}: is a section, give {where}.<key>=value")
            out[k] = merge(out[k], v, where + ".")
        else:
            out[k] = v
    return out


def flatten(d: dict, prefix: str = "") -> dict:
    """A nested config as {dotted name: value}, the names ``--set`` takes (an empty section is a
    value)."""
    out = {}
    for k, v in d.items():
        if isinstance(v, dict) and v:
            out.update(flatten(v, f"{prefix}{k}."))
        else:
            out[prefix + k] = v
    return out


def typed(cls, data: dict, where: str):
    """The dataclass ``cls`` built from config section ``data``, every value checked against its
    annotation first, so a wrong type stops the run at resolution with the setting's name
    rather than deep inside a stage (``--set geometry.train.iterations=many``)."""
    hints = type_hints(cls)
    data = dict(data)
    for k, v in data.items():
        if k not in hints:
            raise ConfigError(f"--set {where}.{k}: unknown setting (known here: {', '.join(sorted(hints))})")
        if dataclasses.is_dataclass(hints[k]):  # a section of its own: typed in turn
            if not isinstance(v, dict):
                raise ConfigError(f"--set {where}.{k}: is a section, give {where}.{k}.<key>=value")
            data[k] = typed(hints[k], v, f"{where}.{k}")
        elif not _matches(v, hints[k]):
            raise ConfigError(f"--set {where}.{k}={json.dumps(v)}: expected {_type_name(hints[k])}")
    try:
        return cls(**data)
    except UserError:
        raise  # the class's own one-line message
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _matches(value, hint) -> bool:
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_matches(value, a) for a in typing.get_args(hint))
    if origin is typing.Literal:
        return value in typing.get_args(hint)
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:  # an int is a float setting's value too (3 for 3.0)
        return isinstance(value, int | float) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    if hint is dict or origin is dict:
        return isinstance(value, dict)
    if hint is list or origin in (list, tuple):
        return isinstance(value, list | tuple)
    return True  # other annotations: the dataclass checks them itself


def _type_name(hint) -> str:
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(hint))
    if typing.get_origin(hint) is typing.Literal:
        return " or ".join(json.dumps(a) for a in typing.get_args(hint))
    return {type(None): "null", int: "a whole number", float: "a number", bool: "true or false",
            str: "a string", dict: "a section"}.get(hint, getattr(hint, "__name__", str(hint)))


def parse_seeds(text: str) -> list[int]:
    """``--seeds``: ``"3"`` -> [0, 1, 2] (the first N run seeds); ``"0,4,7"`` -> those seeds."""
    text = text.strip()
    try:
        if "," not in text:
            n = int(text)
            if n < 1:
                raise ValueError
            return list(range(n))
        seeds = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ConfigError(f"--seeds {text!r}: give a count >= 1 (3: seeds 0, 1, 2) or a list (0,4,7; one "
                          "seed S: 'S,') of whole numbers >= 0") from None
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise ConfigError(f"--seeds {text!r}: give distinct whole numbers >= 0")
    return seeds
