"""The ``trase-bench`` command line.

Subcommands live in their own modules and are imported only when invoked, so ``--help`` and
light commands (``score``, ``datasets``) never pay for torch or numba imports. To add a
command, add one line to ``COMMANDS``: name, "module:click_command", one-line help.
"""

from __future__ import annotations

import sys

import click

from lazyspecs import Registry

COMMANDS = Registry("command")
COMMANDS.add("ablate", "benchmark.commands.ablate:ablate",
             "The paper's ablation studies, run and tabulated.")
COMMANDS.add("datasets", "benchmark.commands.datasets:datasets",
             "List the five *-Mask benchmarks (--json for data).")
COMMANDS.add("edit", "benchmark.commands.edit:edit",
             "Edit a scene: remove, extract, recolour a selection, compose objects of two scenes.")
COMMANDS.add("fit", "benchmark.commands.fit:fit",
             "Fit the method to a capture of one's own (nerfies, COLMAP, transforms json).")
COMMANDS.add("evaluate", "benchmark.commands.evaluate:evaluate",
             "Score a method's predicted masks made elsewhere into runs (kind external).")
COMMANDS.add("figures", "benchmark.commands.figures:figures",
             "The figures page (docs/figures.md): five formats x seeds, measured and written from their data.")
COMMANDS.add("leaderboard", "benchmark.commands.leaderboard:leaderboard",
             "Leaderboards (markdown/latex/csv/html) from results files.")
COMMANDS.add("masks", "benchmark.commands.masks:masks",
             "Per-image anything-masks for a sequence's training views.")
COMMANDS.add("methods", "benchmark.commands.methods:methods",
             "List the methods, built-in and from installed packages (--json for data).")
COMMANDS.add("perf", "benchmark.commands.perf:perf",
             "Measured performance suites (rasterizer numba vs torch ...).")
COMMANDS.add("prepare", "benchmark.commands.prepare:prepare",
             "Raw multi-view downloads -> training frames.")
COMMANDS.add("presets", "benchmark.commands.presets:presets",
             "The presets, or one resolved: every setting's value and where it was declared.")
COMMANDS.add("render", "benchmark.commands.render:render",
             "Frames, an MP4 and a preview of a run, a fitted capture or an edited scene.")
COMMANDS.add("report", "benchmark.commands.report:report",
             "Per-sequence HTML report of a run.")
COMMANDS.add("run", "benchmark.commands.run:run",
             "Run a method on a benchmark (synthetic default without data).")
COMMANDS.add("runs", "benchmark.commands.runs:runs",
             "List runs with their kind, config and protocol.")
COMMANDS.add("score", "benchmark.commands.score:score",
             "Score predicted masks against ground truth.")
COMMANDS.add("select", "benchmark.commands.select:select",
             "Select objects of a fitted capture by clicks -> masks of its views.")
COMMANDS.add("view", "benchmark.commands.view:view",
             "A web viewer of a scene: time, render modes, click selection, edits, export.")
COMMANDS.add("sweep", "benchmark.commands.sweep:sweep",
             "A sweep from a TOML spec, locally or on SLURM (submitit); reruns run only what is missing.")
COMMANDS.add("sweep-status", "benchmark.commands.sweep:sweep_status",
             "done / running / failed / pending per job of a sweep, with errors and logs.")
COMMANDS.add("synth", "benchmark.commands.synth:synth",
             "Generate a synthetic scene in a benchmark's raw format.")


class LazyGroup(click.Group):
    """A click group whose subcommands are imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return COMMANDS.names()

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        return COMMANDS.load(name) if name in COMMANDS else None

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(e.name, e.help) for e in COMMANDS]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="trase-bench")
def cli() -> None:
    """trase-bench: segmentation in novel views of dynamic 3D scenes."""


def main(argv: list[str] | None = None) -> int:
    """Console entry point. Known errors print one line and exit 1, never a traceback. The
    numeric environment is set first, before any command loads numpy, torch or numba."""
    from benchmark import numerics
    from benchmark.errors import is_user_error

    try:
        numerics.apply(numerics.requested_mode(argv))
    except numerics.NumericsError as exc:
        click.echo(f"error: {exc}", err=True)
        return 1
    try:
        cli.main(args=argv, prog_name="trase-bench", standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        return 130
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except SystemExit as exc:  # --help / --version exit through here
        return int(exc.code or 0)
    except Exception as exc:
        if not is_user_error(exc):
            raise
        click.echo(f"error: {exc}", err=True)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
