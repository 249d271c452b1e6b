"""One module per ``trase-bench`` subcommand (registered in ``benchmark.cli.COMMANDS``).

An option's name means one thing in every command:

* ``--runs DIR``: the folder of runs, what ``run`` and ``evaluate`` write into and ``runs``,
  ``leaderboard`` and ``report`` read (default ``runs``);
* ``--run DIR``: one run's folder (``render``, ``edit`` and ``view`` also open a fitted capture
  or an edited scene with it);
* ``--out``: where this command writes its own output, a file or a folder as its help says;
* ``--quiet``: no progress output.

A renamed option keeps its old spelling for one version: declare it with ``old_spelling``.
"""

from __future__ import annotations

import functools

import click
from click.core import ParameterSource


def old_spelling(old: str, new: str):
    """Decorator for a command's callback: the option ``new`` was spelled ``old`` before.

    ``old`` still works, as a hidden option that stands for ``new``, and prints a one-line
    notice on stderr; the help lists only ``new``. Giving both is a usage error. Put it
    between ``@click.command`` and the option's own ``@click.option``::

        @click.command()
        @old_spelling("--results", "--runs")
        @click.option("--runs", "runs_dir", default="runs")
        def runs(runs_dir): ...
    """

    def decorate(f):
        params = getattr(f, "__click_params__", [])
        target = next((p for p in params if new in getattr(p, "opts", ())), None)
        if target is None:
            raise TypeError(f"old_spelling({old!r}, {new!r}): declare the option {new} below this decorator")
        if target.required:
            raise TypeError(f"old_spelling({old!r}, {new!r}): a required option cannot have an old spelling")
        name = "old_spelling_" + old.lstrip("-").replace("-", "_")
        if target.is_flag:
            alias = click.Option([old, name], is_flag=True, hidden=True)
        else:
            alias = click.Option([old, name], type=target.type, multiple=target.multiple, nargs=target.nargs,
                                 hidden=True)

        @functools.wraps(f)
        def callback(*args, **kwargs):
            value = kwargs.pop(name)
            ctx = click.get_current_context()
            if ctx.get_parameter_source(name) is ParameterSource.COMMANDLINE:
                if ctx.get_parameter_source(target.name) is ParameterSource.COMMANDLINE:
                    raise click.UsageError(f"{old} is the old spelling of {new}; give {new} only", ctx=ctx)
                click.echo(f"trase-bench: {old} is now {new} (the old spelling goes in the next version)",
                           err=True)
                kwargs[target.name] = value
            return f(*args, **kwargs)

        callback.__click_params__ = [*params, alias]
        return callback

    return decorate
