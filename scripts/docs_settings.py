"""Writes the docs site's settings reference (reference/settings.md) from the preset tables at
build time (mkdocs-gen-files), so the numbers on the page are the code's: per run preset, every
setting a benchmark's resolution sets away from its config class's default, per benchmark."""

from __future__ import annotations

import json

import mkdocs_gen_files

from benchmark.commands.presets import resolve_rows
from benchmark.datasets import DATASETS
from benchmark.datasets.synthetic import SIZES
from benchmark.pipeline.settings import GEOMETRY_PRESETS

RUN_PRESETS = ("cpu", "paper")


def preset_table(preset: str, keys: list[str]) -> list[str]:
    """A markdown table: one row per setting the preset sets on some benchmark, one column per
    benchmark, the value resolved there (blank: the class's default)."""
    resolved = {k: {key: (v, src) for key, v, src in resolve_rows(k, "trase", preset, None, None, [])} for k in keys}
    shown = sorted({key for rows in resolved.values() for key, (_, src) in rows.items() if not src.startswith("default (")})
    lines = ["| setting | " + " | ".join(keys) + " |", "|---" * (len(keys) + 1) + "|"]
    for key in shown:
        cells = []
        for k in keys:
            value, src = resolved[k][key]
            cells.append("" if src.startswith("default (") else f"`{json.dumps(value, default=str)}`")
        lines.append(f"| `{key}` | " + " | ".join(cells) + " |")
    return lines


SIZED = ("tiny", "small")  # the synthetic scenes whose test-view sizes the tables below resolve


def test_view_size(dataset: str, size: str) -> tuple[int, int]:
    """(W, H) of a synthetic scene's test views: half its rig's native size, as the loader reads it."""
    rig = SIZES[dataset][size]
    return rig.width // 2, rig.height // 2


def sized_table(preset: str, keys: list[str]) -> list[str]:
    """A markdown table of the settings whose value at a synthetic scene's test-view size (SIZED)
    differs from the one resolved without a size (the table above), with the condition that
    declared it."""
    lines = ["| scene | benchmark | setting | value | declared where |", "|---|---|---|---|---|"]
    for k in keys:
        plain = {key: v for key, v, _ in resolve_rows(k, "trase", preset, None, None, [])}
        for size in SIZED:
            w, h = test_view_size(k, size)
            for key, v, src in resolve_rows(k, "trase", preset, None, (w, h), []):
                if plain.get(key) != v and not src.startswith("default (") and not key.endswith(".seed"):
                    lines.append(f"| {size}, {w} x {h} px | {k} | `{key}` | `{json.dumps(v, default=str)}` | {src} |")
    return lines


def page() -> str:
    keys = list(DATASETS)
    intro = ("Generated from the preset tables when the site is built. A run resolves one preset "
             "(`--set preset=NAME`; `auto`: `paper` where torch sees a GPU, `cpu` elsewhere) for its "
             "benchmark; `--set KEY=VALUE` overrides any setting. A blank cell keeps the config "
             "class's default. `trase-bench presets --preset P --dataset D` prints the same with the "
             "file and line that declared each value; the guide is [Presets](../settings.md).")
    out = ["# Settings and presets", "", intro, ""]
    out += ["## The presets", "", "| preset | what it is |", "|---|---|"]
    out += [f"| `{p.name}` | {p.help}{f' (from `{p.base}`)' if p.base else ''} |" for p in GEOMETRY_PRESETS]
    for preset in RUN_PRESETS:
        out += ["", f"## `{preset}`: settings away from the defaults", "", *preset_table(preset, keys)]
        sized = sized_table(preset, keys)
        if len(sized) > 2:
            out += ["", f"Where the `{preset}` preset follows the images' size, its values on the synthetic scenes:", "",
                    *sized]
    return "\n".join(out) + "\n"


with mkdocs_gen_files.open("reference/settings.md", "w") as f:
    f.write(page())
