"""``trase-bench presets [--dataset D] [--method M] [--preset P]``: what a preset resolves to,
setting by setting, and where each value was declared."""

from __future__ import annotations

import json
from pathlib import Path

import click


@click.command()
@click.option("--dataset", default=None, help="A benchmark (its rig and schedule); default: a capture of one's own.")
@click.option("--method", "method_name", default="trase", show_default=True)
@click.option("--preset", default=None, help="The preset to resolve (default: auto, as a run here would); "
                                              "without --dataset/--preset: the list of presets.")
@click.option("--rig", type=click.Choice(["monocular", "multi-view"]), default=None,
              help="A capture of one's own: its camera rig (default monocular); a benchmark has its own.")
@click.option("--image-size", default=None, metavar="WxH",
              help="Images a run evaluates at (the cpu presets' training scale follows them).")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help="As for `run`: shown as --set.")
@click.option("--all", "show_all", is_flag=True, help="Every setting, the config classes' defaults too.")
@click.option("--json", "as_json", is_flag=True, help="One JSON object: setting -> {value, declared}.")
def presets(dataset, method_name, preset, rig, image_size, overrides, show_all, as_json) -> None:
    """The presets, or one resolved: value and declaration of every setting it sets."""
    from benchmark.pipeline.settings import GEOMETRY_PRESETS

    if dataset is None and preset is None and not overrides:
        click.echo("presets (--set preset=NAME; auto: paper with a GPU, cpu without):")
        width = max(len(n) for n in GEOMETRY_PRESETS.names())
        for p in GEOMETRY_PRESETS:
            base = f" [from {p.base}]" if p.base else ""
            click.echo(f"  {p.name:<{width}} {p.help}{base}")
        click.echo("resolve one: trase-bench presets --preset cpu --dataset hypernerf [--method M] [--all]")
        return
    rows = resolve_rows(dataset, method_name, preset, rig, _size(image_size), list(overrides))
    if as_json:
        click.echo(json.dumps({k: {"value": v, "declared": s} for k, v, s in rows}, indent=1, default=str))
        return
    shown = [r for r in rows if show_all or not r[2].startswith("default (")]
    width = max(len(k) for k, _, _ in shown)
    for key, value, source in shown:
        click.echo(f"{key:<{width}}  {json.dumps(value, default=str):<22}  {source}")
    if not show_all:
        click.echo(f"({len(rows) - len(shown)} more settings keep their config class's default: --all shows them)")


def resolve_rows(dataset: str | None, method_name: str, preset: str | None, rig: str | None,
                 image_size: tuple[int, int] | None, overrides: list[str]) -> list[tuple[str, object, str]]:
    """(setting, value, where declared) of every setting a run would resolve."""
    from benchmark.config import flatten, parse_overrides
    from benchmark.datasets import get_dataset
    from benchmark.methods import get_method
    from benchmark.pipeline.settings import capture_settings, run_settings

    ov = parse_overrides(overrides)
    if preset is not None:
        ov["preset"] = preset
    method = get_method(method_name)
    if dataset is not None:
        if rig is not None:
            raise click.UsageError("--rig describes a capture of one's own; a benchmark has its own rig")
        settings = run_settings(method, get_dataset(dataset), "synthetic", ov, image_size)
    else:
        settings = capture_settings(method, rig != "multi-view", {}, ov, image_size)
    flat = flatten(settings.to_dict())
    run_level = "the run (benchmark.pipeline.settings)"
    return [(k, v, _short(_source(settings.sources, k, run_level))) for k, v in flat.items()]


def _source(sources: dict[str, str], key: str, otherwise: str) -> str:
    """Where ``key`` was declared; a key inside a free-form section (``params``) without a
    declaration of its own: its section's."""
    while key not in sources and "." in key:
        key = key.rsplit(".", 1)[0]
    return sources.get(key, otherwise)


def _short(source: str) -> str:
    """A declaration's path relative to the installed packages' folder."""
    import trase

    root = str(Path(trase.__file__).resolve().parents[1]) + "/"
    return source.replace(root, "")


def _size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"{text!r}: give WxH, e.g. 960x536", param_hint="--image-size") from None
    return w, h
