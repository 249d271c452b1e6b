"""``trase-bench datasets [--json]``: the five benchmarks, their sequences and splits."""

from __future__ import annotations

import json

import click

from benchmark.datasets.registry import DATASETS
from benchmark.methods.trase_presets import trase_settings


@click.command()
@click.option("--json", "as_json", is_flag=True, help="Print the registry as JSON.")
def datasets(as_json: bool) -> None:
    """List the five *-Mask benchmarks: sequences, split, resolution, frames, method defaults,
    and the built-in synthetic sequences every benchmark has without real data."""
    if as_json:
        click.echo(json.dumps({k: s.to_dict() for k, s in DATASETS.items()}, indent=2))
        return
    try:
        from rich.console import Console
        from rich.table import Table
    except ImportError:  # rich is a dependency; plain text keeps the command usable without it
        for s in DATASETS.values():
            click.echo(f"{s.key} ({s.display_name}): {', '.join(s.sequences)}")
            click.echo(f"  split: {s.split}")
        click.echo(builtin_sequences())
        return
    times = sorted({s.time_rule for s in DATASETS.values()})
    table = Table(title="trase-bench datasets", show_lines=True,
                  caption="time: " + " | ".join(times))
    table.add_column("benchmark", no_wrap=True)
    table.add_column("sequences", no_wrap=True)
    table.add_column("split", overflow="fold", min_width=16)
    table.add_column("resolution, frames", overflow="fold")
    table.add_column("defaults", no_wrap=True)
    for s in DATASETS.values():
        res = f"{s.resolution[0]}x{s.resolution[1]}" if s.resolution else f"rgb/{s.downscale}x"
        if s.frame_ranges:
            frames = "; ".join(f"{k} {a}-{b}" for k, (a, b) in s.frame_ranges.items())
            if len({v for v in s.frame_ranges.values()}) == 1:
                a, b = next(iter(s.frame_ranges.values()))
                frames = f"frames {a}-{b}"
        else:
            frames = "dataset.json items"
        trase = trase_settings("paper", s.key)  # the reference method's settings for this benchmark
        defaults = (f"Np {trase.features.n_pixels}\nM' {trase.features.n_masks:g}\nfilter {trase.filter_threshold}\n"
                    f"warm-up {s.warm_up}\ndensify {s.densify_until}")
        kind = "monocular" if s.monocular else "multi-view"
        table.add_row(f"{s.key}\n{s.display_name}\n{s.format}, {kind}", "\n".join(s.sequences),
                      s.split, f"{res}\n{frames}", defaults)
    console = Console()
    if not console.is_terminal:  # a pipe or a file gets the whole table, not 80 columns
        console = Console(width=200)
    console.print(table)
    console.print(builtin_sequences())


def builtin_sequences() -> str:
    """The synthetic sequences, one per size and difficulty, that each benchmark runs without data."""
    from benchmark.datasets.synthetic import DIFFICULTIES, SIZE_NAMES
    from benchmark.datasets.synthetic.generate import sequence_name

    names = ", ".join(sequence_name(size, d) for d in DIFFICULTIES for size in SIZE_NAMES)
    return (f"built-in synthetic sequences of every benchmark (generated on first use, no data needed): {names}; "
            "`trase-bench synth --size tiny|small|medium` writes one anywhere")
